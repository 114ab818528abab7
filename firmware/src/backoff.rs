//! Backing off failed authentications, for all network sessions together.
//!
//! Every challenge response that does not verify is counted (reported in `Status`) and
//! closes authentication, on every connection at once, for a delay: [`FIRST_DELAY_US`]
//! after one failure, doubling with each further failure in a row up to [`MAX_DELAY_US`].
//! During the delay `AuthChallenge` and `AuthResponse` are answered `auth-backoff`, so
//! opening more connections does not buy more guesses. A success ends the run of failures.

/// The delay after a single failure.
pub const FIRST_DELAY_US: u64 = 250_000;

/// The longest delay, however many failures came in a row.
pub const MAX_DELAY_US: u64 = 8_000_000;

/// Failed authentications and when the next attempt is accepted.
#[derive(Clone, Debug, Default)]
pub(crate) struct AuthBackoff {
    /// Failures since start-up.
    failures: u32,
    /// Failures since the last success.
    in_a_row: u32,
    /// No attempt is accepted before this time.
    closed_until_us: u64,
}

impl AuthBackoff {
    /// How long until an attempt is accepted, when `now_us` is still inside a delay.
    pub(crate) fn wait_us(&self, now_us: u64) -> Option<u64> {
        (now_us < self.closed_until_us).then(|| self.closed_until_us - now_us)
    }

    /// Counts a failure at `now_us` and starts the next delay.
    pub(crate) fn failed(&mut self, now_us: u64) {
        self.failures = self.failures.saturating_add(1);
        self.in_a_row = self.in_a_row.saturating_add(1);
        let doublings = self.in_a_row.saturating_sub(1).min(16);
        let delay = FIRST_DELAY_US
            .saturating_mul(1 << doublings)
            .min(MAX_DELAY_US);
        self.closed_until_us = now_us.saturating_add(delay);
    }

    /// Ends the run of failures.
    pub(crate) fn succeeded(&mut self) {
        self.in_a_row = 0;
    }

    /// When attempts are accepted again (in the past when they are now).
    pub(crate) fn reopens_at_us(&self) -> u64 {
        self.closed_until_us
    }

    /// Failures since start-up.
    pub(crate) fn failures(&self) -> u32 {
        self.failures
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn delays_double_with_failures_in_a_row_up_to_the_cap_and_a_success_resets_them() {
        let mut backoff = AuthBackoff::default();
        assert_eq!(backoff.wait_us(0), None);
        let mut now = 1_000_000;
        let mut delays = Vec::new();
        for _ in 0..8 {
            backoff.failed(now);
            delays.push(backoff.wait_us(now).unwrap());
            now += delays.last().unwrap();
            assert_eq!(
                backoff.wait_us(now),
                None,
                "open again once the delay ran out"
            );
        }
        assert_eq!(
            delays,
            [
                250_000, 500_000, 1_000_000, 2_000_000, 4_000_000, 8_000_000, 8_000_000, 8_000_000
            ]
        );
        assert_eq!(backoff.failures(), 8);
        backoff.succeeded();
        backoff.failed(now);
        assert_eq!(backoff.wait_us(now), Some(FIRST_DELAY_US));
        assert_eq!(
            backoff.wait_us(now + 100_000),
            Some(FIRST_DELAY_US - 100_000)
        );
        assert_eq!(
            backoff.failures(),
            9,
            "the count since start-up survives a success"
        );
    }
}
