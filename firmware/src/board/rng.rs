//! The entropy behind challenge and boot nonces (and the network stack's seed): a ChaCha20
//! generator seeded at boot from the board's entropy source, whitened by SHA-256.
//!
//! The board module picks the source and calls [`seed`] before the core starts: the
//! RP2350's TRNG on the Pico 2 W, the ring oscillator on the RP2040 (one biased, correlated
//! bit per read of its RANDOMBIT register, so its bits are never used directly). An image
//! that never calls [`seed`] (the emulator's) is seeded from the ring oscillator at the
//! first draw. [`SEED_SAMPLES`] bytes of the source are hashed with SHA-256 together with
//! the uptime in microseconds and a label; the digest seeds ChaCha20 (`rand_chacha`).
//!
//! Uniqueness does not rest on this entropy: the core mixes a persisted boot counter, the
//! board id and a draw counter into every challenge (`crate::nonce`).

use core::cell::RefCell;

use embassy_rp::clocks::RoscRng;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use rand_chacha::ChaCha20Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};
use sha2::{Digest, Sha256};

use super::now_us;
use crate::session::RngSource;

/// Source bytes hashed into the seed (from the ring oscillator: eight RANDOMBIT reads each).
pub const SEED_SAMPLES: usize = 256;

/// Domain separation for the seed.
const SEED_CONTEXT: &[u8] = b"optalign-nonce-seed-v1";

/// The generator, seeded at its first use.
static GENERATOR: Mutex<CriticalSectionRawMutex, RefCell<Option<ChaCha20Rng>>> =
    Mutex::new(RefCell::new(None));

/// The whitened generator as the core's [`RngSource`].
pub struct Nonces;

impl RngSource for Nonces {
    fn fill(&mut self, buf: &mut [u8]) {
        GENERATOR.lock(|cell| {
            cell.borrow_mut()
                .get_or_insert_with(|| seeded(&mut RoscRng))
                .fill_bytes(buf)
        });
    }
}

/// (Re)seeds the generator from `entropy`.
pub fn seed(entropy: &mut impl RngCore) {
    let generator = seeded(entropy);
    GENERATOR.lock(|cell| *cell.borrow_mut() = Some(generator));
}

/// A generator seeded from hashed samples of `entropy` and the uptime.
fn seeded(entropy: &mut impl RngCore) -> ChaCha20Rng {
    let mut hasher = Sha256::new();
    hasher.update(SEED_CONTEXT);
    hasher.update(now_us().to_le_bytes());
    let mut samples = [0u8; 32];
    for _ in 0..SEED_SAMPLES / samples.len() {
        entropy.fill_bytes(&mut samples);
        hasher.update(samples);
    }
    hasher.update(now_us().to_le_bytes());
    ChaCha20Rng::from_seed(hasher.finalize().into())
}
