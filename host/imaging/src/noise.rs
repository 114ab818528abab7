//! How far one pixel scatters, place by place: black clips the read noise (to 0.58 of it at black),
//! so one number would set thresholds too high in the dark or too low on a bright beam's halo.

use super::cells::{CellSums, around, f64_sum};
use super::tuning::{LEVEL_REACH, NOISE_CELL};

fn normal(t: f64) -> (f64, f64) {
    let density = (-0.5 * t * t).exp() / (2.0 * std::f64::consts::PI).sqrt();
    (density, optalign_optics::normal_cdf(t))
}

/// The mean of `max(0, t + Z)`, `Z` standard normal: `t Φ(t) + φ(t)`.
pub(crate) fn clipped_normal_mean(t: f64) -> f64 {
    let (density, cdf) = normal(t);
    t * cdf + density
}

/// The standard deviation of `max(0, t + Z)` for a standard normal `Z`.
fn clipped_normal_spread(t: f64) -> f64 {
    let (density, cdf) = normal(t);
    let mean = clipped_normal_mean(t);
    ((t * t + 1.0) * cdf + t * density - mean * mean)
        .max(0.0)
        .sqrt()
}

/// The level `t` whose clipped mean is `mean`, by bisection (the mean grows with `t`).
fn level_of_clipped_mean(mean: f64) -> f64 {
    let (mut low, mut high) = (-6.0, mean.max(0.0) + 1.0);
    for _ in 0..40 {
        let mid = 0.5 * (low + high);
        if clipped_normal_mean(mid) < mean {
            low = mid;
        } else {
            high = mid;
        }
    }
    0.5 * (low + high)
}

/// One pixel's scatter per cell of a frame, gray levels.
#[derive(Clone, Debug)]
pub struct NoiseMap {
    columns: usize,
    rows: usize,
    spread: Vec<f32>,
}

impl NoiseMap {
    pub(crate) fn uniform(width: usize, height: usize, noise: f64) -> Self {
        let (columns, rows) = (width.div_ceil(NOISE_CELL), height.div_ceil(NOISE_CELL));
        Self {
            columns,
            rows,
            spread: vec![noise as f32; columns * rows],
        }
    }

    /// Per cell, a clipped normal's scatter at the cell's mean level, never below that at black.
    pub(crate) fn clipped(frame: &optalign_optics::Frame, noise: f64) -> Self {
        let (width, height) = (frame.width() as usize, frame.height() as usize);
        let cells = CellSums::new(frame.pixels(), width, height, NOISE_CELL, f64_sum);
        let (columns, rows) = (cells.columns, cells.rows);
        let floor = noise * clipped_normal_spread(0.0);
        let spread = (0..columns * rows)
            .map(|c| {
                let (sum, count) = around(c, LEVEL_REACH, columns, rows)
                    .fold((0.0, 0.0), |(s, n), i| {
                        (s + cells.sums[i], n + cells.counts[i])
                    });
                let mean = sum * f64::from(frame.levels_per_count()) / count.max(1.0) / noise;
                (noise * clipped_normal_spread(level_of_clipped_mean(mean))).max(floor) as f32
            })
            .collect();
        Self {
            columns,
            rows,
            spread,
        }
    }

    /// The scatter of pixel (`x`, `y`), gray levels.
    pub fn at(&self, x: usize, y: usize) -> f32 {
        let cell = |v: usize, cells: usize| (v / NOISE_CELL).min(cells - 1);
        self.spread[cell(y, self.rows) * self.columns + cell(x, self.columns)]
    }

    /// The scatter of `later - gain * earlier`, `self` being the later frame's map.
    pub(crate) fn of_difference(&self, earlier: &NoiseMap, gain: f64) -> Self {
        let gain = gain as f32;
        Self {
            spread: self
                .spread
                .iter()
                .zip(&earlier.spread)
                .map(|(a, b)| a.hypot(gain * b))
                .collect(),
            ..*self
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipped_normal_statistics_match_their_limits() {
        // Far above black nothing clips; at black half the values read 0.
        assert!((clipped_normal_mean(6.0) - 6.0).abs() < 1e-6);
        assert!((clipped_normal_spread(6.0) - 1.0).abs() < 1e-6);
        assert!((clipped_normal_mean(0.0) - 0.398_942).abs() < 1e-5);
        assert!((clipped_normal_spread(0.0) - 0.583_819).abs() < 1e-5);
        for t in [-2.0, -0.5, 0.1, 1.3, 3.0] {
            let back = level_of_clipped_mean(clipped_normal_mean(t));
            assert!((back - t).abs() < 1e-6, "{t} -> {back}");
        }
    }
}
