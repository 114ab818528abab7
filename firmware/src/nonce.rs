//! Challenge nonces unique by construction, not by the luck of the entropy source.
//!
//! A session key is `HMAC(key, nonce || client nonce)` and frame counters restart at 1, so a
//! challenge nonce issued twice would let a recorded session be replayed verbatim. Each
//! nonce therefore carries, in the clear, the board's boot counter (persisted before the
//! first nonce of a boot is issued) and a draw counter that restarts at each boot: no two
//! nonces of one board are equal, whatever the entropy source yields. The last bytes mix
//! both counters with the board id and fresh entropy through SHA-256, so boards sharing a
//! key (same counters, and entropy that might repeat) still issue different nonces.
//!
//! Layout ([`NONCE_LEN`] bytes): boot counter (u32, little endian), draw counter (48 bits,
//! little endian), then the first [`MIX_LEN`] bytes of
//! `SHA-256(CONTEXT || board id || boot counter || draw counter || 32 entropy bytes)`.

use optalign_protocol::auth::Nonce;
use optalign_protocol::limits::NONCE_LEN;
use sha2::{Digest, Sha256};

use crate::session::RngSource;

/// Bytes of the boot counter in a nonce.
const BOOT_LEN: usize = 4;
/// Bytes of the draw counter in a nonce.
const DRAW_LEN: usize = 6;
/// Bytes of the board id and entropy mix in a nonce.
pub const MIX_LEN: usize = NONCE_LEN - BOOT_LEN - DRAW_LEN;

/// Domain separation for the mix.
const CONTEXT: &[u8] = b"optalign-nonce-v1";

/// The draw counter's first value beyond its field.
const DRAWS_END: u64 = 1 << (8 * DRAW_LEN);

/// No nonce can be issued.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NonceError {
    /// The boot counter is not persisted yet (the storage refused or failed the write).
    BootNotCounted,
    /// Every draw counter value of this boot is used up (2^48 challenges): reboot.
    Exhausted,
}

/// Issues the nonces of one boot of one board.
#[derive(Clone, Debug)]
pub struct NonceIssuer {
    board_id: u64,
    /// This boot's number, once it is persisted.
    boot: Option<u32>,
    drawn: u64,
}

impl NonceIssuer {
    /// Nonces for the board `board_id`; none is issued before [`Self::counted`].
    pub fn new(board_id: u64) -> Self {
        Self {
            board_id,
            boot: None,
            drawn: 0,
        }
    }

    /// Whether this boot's number is persisted.
    pub fn is_counted(&self) -> bool {
        self.boot.is_some()
    }

    /// Records that `boot`, this boot's number, is persisted.
    pub fn counted(&mut self, boot: u32) {
        self.boot = Some(boot);
    }

    /// Takes the next draw counter: the nonce it makes ([`Draw::nonce`]) is this boot's
    /// next, mixed with fresh entropy when it is made.
    pub fn reserve(&mut self) -> Result<Draw, NonceError> {
        let boot = self.boot.ok_or(NonceError::BootNotCounted)?;
        if self.drawn >= DRAWS_END {
            return Err(NonceError::Exhausted);
        }
        let draw = self.drawn;
        self.drawn += 1;
        Ok(Draw {
            board_id: self.board_id,
            boot,
            draw,
        })
    }
}

/// One nonce's counters, reserved and not made yet (the making hashes: see
/// [`crate::crypto`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Draw {
    board_id: u64,
    boot: u32,
    draw: u64,
}

impl Draw {
    /// The nonce, mixing in entropy from `rng`.
    pub fn nonce(&self, rng: &mut dyn RngSource) -> Nonce {
        let draw = self.draw.to_le_bytes();
        let mut entropy = [0u8; 32];
        rng.fill(&mut entropy);
        let mix = Sha256::new()
            .chain_update(CONTEXT)
            .chain_update(self.board_id.to_le_bytes())
            .chain_update(self.boot.to_le_bytes())
            .chain_update(&draw[..DRAW_LEN])
            .chain_update(entropy)
            .finalize();
        let mut nonce = [0u8; NONCE_LEN];
        let (counters, mixed) = nonce.split_at_mut(BOOT_LEN + DRAW_LEN);
        counters[..BOOT_LEN].copy_from_slice(&self.boot.to_le_bytes());
        counters[BOOT_LEN..].copy_from_slice(&draw[..DRAW_LEN]);
        mixed.copy_from_slice(&mix[..MIX_LEN]);
        nonce
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Entropy that never changes: the worst a broken source can do.
    struct Stuck;

    impl RngSource for Stuck {
        fn fill(&mut self, buf: &mut [u8]) {
            buf.fill(0x5A);
        }
    }

    #[test]
    fn nothing_is_issued_before_the_boot_is_counted() {
        let mut nonces = NonceIssuer::new(1);
        assert_eq!(nonces.reserve(), Err(NonceError::BootNotCounted));
        nonces.counted(1);
        assert!(nonces.reserve().is_ok());
    }

    #[test]
    fn stuck_entropy_still_gives_distinct_nonces_across_draws_boots_and_boards() {
        let mut seen = std::collections::HashSet::new();
        for board in [1u64, 2] {
            for boot in [1u32, 2, u32::MAX] {
                let mut nonces = NonceIssuer::new(board);
                nonces.counted(boot);
                for _ in 0..100 {
                    let nonce = nonces.reserve().unwrap().nonce(&mut Stuck);
                    assert!(seen.insert(nonce), "repeated {nonce:?}");
                }
            }
        }
    }

    #[test]
    fn the_counters_are_in_the_clear() {
        let mut nonces = NonceIssuer::new(7);
        nonces.counted(0x0102_0304);
        nonces.reserve().unwrap();
        let second = nonces.reserve().unwrap().nonce(&mut Stuck);
        assert_eq!(second[..BOOT_LEN], [4, 3, 2, 1]);
        assert_eq!(second[BOOT_LEN..BOOT_LEN + DRAW_LEN], [1, 0, 0, 0, 0, 0]);
    }

    #[test]
    fn the_draw_counter_does_not_wrap() {
        let mut nonces = NonceIssuer::new(7);
        nonces.counted(1);
        nonces.drawn = DRAWS_END - 1;
        assert!(nonces.reserve().is_ok());
        assert_eq!(nonces.reserve(), Err(NonceError::Exhausted));
    }
}
