//! Hidden initial offsets: the fixed misalignment each numbered seed starts from, drawn
//! deterministically from (scene parameters, seed number).
//!
//! Each scene draws from its own ChaCha8 stream, so seed 3 of the Michelson and seed 3 of the
//! relay are unrelated. The paper's ten runs correspond to [`DEFAULT_SEEDS`].

use std::ops::Range;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use thiserror::Error;

use crate::relay::starts_dark;
use crate::scenario::{CavityParams, MichelsonParams, RelayParams};

/// The ten fixed seeds shared by every policy.
pub const DEFAULT_SEEDS: Range<u64> = 0..10;

/// How many relay draws are tried before giving up on a configuration that never starts dark.
pub const MAX_RELAY_DRAWS: u32 = 10_000;

/// Why offsets could not be drawn.
#[derive(Debug, Clone, PartialEq, Eq, Error)]
pub enum SeedError {
    /// The relay parameters let light reach C8 for every draw tried.
    #[error(
        "relay seed {seed}: light reached C8 in all {draws} draws; widen relay.offset_range_steps"
    )]
    RelayNeverDark {
        /// The seed number.
        seed: u64,
        /// Draws tried.
        draws: u32,
    },
}

/// Stream ids keep the scenes' draws independent.
const MICHELSON_STREAM: u64 = 1;
const CAVITY_STREAM: u64 = 2;
const RELAY_STREAM: u64 = 3;

fn rng(seed: u64, stream: u64) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(stream);
    rng
}

fn uniform(rng: &mut ChaCha8Rng, range: i32) -> i32 {
    rng.random_range(-range..=range)
}

/// Michelson offsets `[m1 horizontal, m1 vertical, m2 horizontal, m2 vertical]`: horizontal
/// uniform in +-`horizontal_offset_range_steps`, vertical in +-`vertical_offset_range_steps`.
pub fn michelson_offsets(params: &MichelsonParams, seed: u64) -> [i32; 4] {
    let mut rng = rng(seed, MICHELSON_STREAM);
    let (h, v) = (
        params.horizontal_offset_range_steps,
        params.vertical_offset_range_steps,
    );
    [h, v, h, v].map(|range| uniform(&mut rng, range))
}

/// Cavity offsets `[x (motor 3), y (motor 1)]`, uniform in the configured ranges.
pub fn cavity_offsets(params: &CavityParams, seed: u64) -> [i32; 2] {
    let mut rng = rng(seed, CAVITY_STREAM);
    [params.x_offset_range_steps, params.y_offset_range_steps].map(|range| uniform(&mut rng, range))
}

/// Relay offsets for the 8 axes, uniform in +-`offset_range_steps`, redrawn (from the same
/// stream, so deterministically) until no light reaches C8 with the shafts at zero.
pub fn relay_offsets(params: &RelayParams, seed: u64) -> Result<[i32; 8], SeedError> {
    let mut rng = rng(seed, RELAY_STREAM);
    for _ in 0..MAX_RELAY_DRAWS {
        let offsets = [0; 8].map(|_: i32| uniform(&mut rng, params.offset_range_steps));
        if starts_dark(params, &offsets) {
            return Ok(offsets);
        }
    }
    Err(SeedError::RelayNeverDark {
        seed,
        draws: MAX_RELAY_DRAWS,
    })
}
