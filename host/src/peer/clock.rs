//! The simulated peer's clock: real time (optionally scaled) or event-driven "instant"
//! time, where the motion loop jumps straight to the next step deadline.

use std::time::{Duration, Instant};

/// How simulated time relates to wall-clock time.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TimeMode {
    /// Simulated time runs `scale` times as fast as the wall clock (1.0 = real time).
    Scaled(f64),
    /// Simulated time jumps to each deadline: every move completes as soon as it starts.
    Instant,
}

/// A monotonic microsecond clock for the firmware core.
#[derive(Debug)]
pub struct SimClock {
    mode: TimeMode,
    origin: Instant,
    jumped_us: u64,
}

impl SimClock {
    pub fn new(mode: TimeMode) -> Self {
        Self {
            mode,
            origin: Instant::now(),
            jumped_us: 0,
        }
    }

    pub fn mode(&self) -> TimeMode {
        self.mode
    }

    /// Current simulated time in microseconds.
    pub fn now_us(&self) -> u64 {
        match self.mode {
            TimeMode::Scaled(scale) => (self.origin.elapsed().as_secs_f64() * 1e6 * scale) as u64,
            TimeMode::Instant => self.jumped_us,
        }
    }

    /// In instant mode, moves time forward to `deadline_us` (never backwards).
    pub fn jump_to(&mut self, deadline_us: u64) {
        if self.mode == TimeMode::Instant {
            self.jumped_us = self.jumped_us.max(deadline_us);
        }
    }

    /// Wall-clock time until simulated `deadline_us`, in scaled mode.
    pub fn wall_time_until(&self, deadline_us: u64) -> Duration {
        match self.mode {
            TimeMode::Scaled(scale) => {
                let sim = deadline_us.saturating_sub(self.now_us());
                // Saturates rather than panics for a scale too small to wait for.
                Duration::try_from_secs_f64(sim as f64 / 1e6 / scale).unwrap_or(Duration::MAX)
            }
            TimeMode::Instant => Duration::ZERO,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn instant_time_only_moves_forward_on_jumps() {
        let mut clock = SimClock::new(TimeMode::Instant);
        assert_eq!(clock.now_us(), 0);
        clock.jump_to(500);
        clock.jump_to(200);
        assert_eq!(clock.now_us(), 500);
        assert_eq!(clock.wall_time_until(10_000), Duration::ZERO);
    }

    #[test]
    fn scaled_time_converts_deadlines_to_wall_time() {
        let clock = SimClock::new(TimeMode::Scaled(10.0));
        let wait = clock.wall_time_until(clock.now_us() + 1_000_000);
        assert!(
            wait <= Duration::from_millis(100) && wait > Duration::from_millis(90),
            "{wait:?}"
        );
    }
}
