//! Camera read-out shared by the scenes: turns a row of light intensity (gray levels of an
//! 8-bit frame) into pixels at the camera's depth by adding the background level and
//! per-pixel noise, then saturating.
//!
//! Noise comes from one shared table of 4M approximately Gaussian samples (each the sum of
//! four bytes of a splitmix64 hash, so close to Gaussian with tails cut at 3.4 sigma), built
//! once per process. A frame reads the table in raster order from a start drawn from
//! (scene key, frame index): the noise is fixed by those two numbers, never repeats within a
//! frame of up to 4M pixels, and costs one table read per pixel.

use std::sync::OnceLock;

use crate::frame::MAX_SIDE_PX;
use crate::scenario::NoiseParams;

/// Standard deviation of a sum of four independent uniform bytes.
const BYTE_SUM_STD: f64 = 147.801_89;
/// Mean of a sum of four independent uniform bytes.
const BYTE_SUM_MEAN: f64 = 510.0;
/// The splitmix64 increment.
const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;
/// Samples in the noise table (before the wrap-around padding).
const TABLE_LEN: usize = 1 << 22;
/// Table entries per standard deviation of noise.
const TABLE_STEPS_PER_STD: f64 = 16.0;
/// Adding this to a float in [0, 65536) leaves its nearest integer in the low mantissa bits.
const ROUNDING_MAGIC: f32 = 8_388_608.0;

/// The splitmix64 output function: a bijective 64-bit mixer.
pub(crate) fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// A key that fixes a scene's noise: derived from the noise seed and the hidden offsets, so
/// a seed number determines every frame.
pub(crate) fn scene_key(seed: u64, offsets: &[i32]) -> u64 {
    offsets.iter().fold(mix64(seed ^ GAMMA), |key, &o| {
        mix64(key ^ u64::from(o as u32).wrapping_mul(GAMMA))
    })
}

/// The shared noise table: `TABLE_LEN` samples in units of 1/16 standard deviation, followed
/// by a copy of its first `MAX_SIDE_PX` samples so any row can be read contiguously.
fn noise_table() -> &'static [i8] {
    static TABLE: OnceLock<Vec<i8>> = OnceLock::new();
    TABLE.get_or_init(|| {
        const LOW_BYTES: u64 = 0x00ff_00ff_00ff_00ff;
        let mut table = Vec::with_capacity(TABLE_LEN + MAX_SIDE_PX as usize);
        for counter in 0..(TABLE_LEN / 2) as u64 {
            let h = mix64(counter.wrapping_mul(GAMMA));
            let sums = (h & LOW_BYTES) + ((h >> 8) & LOW_BYTES);
            let first = (sums & 0xffff) + ((sums >> 16) & 0xffff);
            let second = ((sums >> 32) & 0xffff) + (sums >> 48);
            for sum in [first, second] {
                let z = (sum as f64 - BYTE_SUM_MEAN) / BYTE_SUM_STD;
                table.push((z * TABLE_STEPS_PER_STD).round() as i8);
            }
        }
        table.extend_from_within(..MAX_SIDE_PX as usize);
        table
    })
}

/// Read-out of one frame.
pub(crate) struct Readout {
    table: &'static [i8],
    /// Where this frame starts reading the table.
    start: usize,
    /// Counts per table unit.
    scale: f32,
    /// Dark level, counts.
    background: f32,
    /// Saturation, counts.
    saturation: f32,
    /// Counts per gray level of an 8-bit frame.
    gain: f32,
    /// Largest pixel value.
    full_scale: u16,
}

impl Readout {
    pub(crate) fn new(noise: &NoiseParams, scene_key: u64, frame_index: u64) -> Self {
        let key = mix64(scene_key ^ mix64(frame_index.wrapping_add(GAMMA)));
        let full_scale = noise.full_scale();
        let gain = f32::from(full_scale) / 255.0;
        Self {
            table: noise_table(),
            start: (key % TABLE_LEN as u64) as usize,
            scale: (noise.std / TABLE_STEPS_PER_STD) as f32 * gain,
            background: noise.background_level as f32 * gain,
            saturation: noise.saturation_level as f32 * gain,
            gain,
            full_scale,
        }
    }

    /// Largest pixel value of the frames read out.
    pub(crate) fn full_scale(&self) -> u16 {
        self.full_scale
    }

    /// Writes row `y`: background + `signal` (gray levels, zero where `None`) + noise,
    /// saturated, in counts. `signal`, when given, has one entry per pixel of `out`.
    pub(crate) fn finish_row(&self, y: u32, signal: Option<&[f32]>, out: &mut [u16]) {
        let w = out.len();
        let at = (self.start + y as usize * w) % TABLE_LEN;
        let noise = &self.table[at..at + w];
        let (scale, bg, sat, gain) = (self.scale, self.background, self.saturation, self.gain);
        match signal {
            Some(signal) => {
                for ((o, &n), s) in out.iter_mut().zip(noise).zip(signal) {
                    *o = quantise(bg + s * gain + f32::from(n) * scale, sat);
                }
            }
            None => {
                for (o, &n) in out.iter_mut().zip(noise) {
                    *o = quantise(bg + f32::from(n) * scale, sat);
                }
            }
        }
    }
}

impl Readout {
    /// The pixel value of `signal` gray levels above the dark level, without noise.
    pub(crate) fn level(&self, signal: f64) -> u16 {
        quantise(self.background + signal as f32 * self.gain, self.saturation)
    }
}

/// Rounds a value to the nearest count, clipping at 0 and at `saturation` (<= 65535).
fn quantise(value: f32, saturation: f32) -> u16 {
    // Branch-free rounding that vectorises: the clipped value plus 2^23 holds its nearest
    // integer in the low mantissa bits.
    ((value.max(0.0).min(saturation) + ROUNDING_MAGIC).to_bits() & 0xffff) as u16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantise_rounds_and_clips() {
        assert_eq!(quantise(-3.0, 255.0), 0);
        assert_eq!(quantise(f32::NAN, 255.0), 0);
        assert_eq!(quantise(3.4, 255.0), 3);
        assert_eq!(quantise(3.6, 255.0), 4);
        assert_eq!(quantise(254.7, 255.0), 255);
        assert_eq!(quantise(1000.0, 255.0), 255);
        assert_eq!(quantise(1000.0, 200.0), 200);
        assert_eq!(quantise(65534.6, 65535.0), 65535);
        assert_eq!(quantise(4000.4, 4095.0), 4000);
    }

    #[test]
    fn noise_table_is_standardised_and_wraps() {
        let table = noise_table();
        let n = TABLE_LEN as f64;
        let values = table[..TABLE_LEN]
            .iter()
            .map(|&v| f64::from(v) / TABLE_STEPS_PER_STD);
        let (sum, sum2) = values.fold((0.0, 0.0), |(s, s2), v| (s + v, s2 + v * v));
        assert!((sum / n).abs() < 0.01);
        assert!((sum2 / n - 1.0).abs() < 0.01);
        assert_eq!(table[TABLE_LEN..], table[..MAX_SIDE_PX as usize]);
    }
}
