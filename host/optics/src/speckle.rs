//! A precomputed, periodic speckle pattern: the granular intensity of light scattered from a
//! clipped beam. Built once per scene by low-pass filtering complex white noise (a circular
//! complex Gaussian field) and squaring its magnitude, which gives fully developed speckle
//! (exponentially distributed intensity) with grains about `grain_px` across.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Side of the square tile, px (a power of two, so lookups wrap with a mask).
const SIZE: usize = 512;
const MASK: usize = SIZE - 1;

/// A seamless SIZE x SIZE speckle intensity tile with mean 1.
#[derive(Debug, Clone)]
pub(crate) struct SpeckleTile {
    data: Vec<f32>,
}

impl SpeckleTile {
    pub(crate) fn new(grain_px: f64, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut re: Vec<f32> = (0..SIZE * SIZE)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let mut im: Vec<f32> = (0..SIZE * SIZE)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let kernel = gaussian_kernel(grain_px);
        for field in [&mut re, &mut im] {
            blur_rows(field, &kernel);
            transpose(field);
            blur_rows(field, &kernel);
        }
        let mut data: Vec<f32> = re.iter().zip(&im).map(|(a, b)| a * a + b * b).collect();
        let mean = data.iter().map(|&v| f64::from(v)).sum::<f64>() / data.len() as f64;
        let scale = (1.0 / mean) as f32;
        data.iter_mut().for_each(|v| *v *= scale);
        Self { data }
    }

    /// Intensity at (x, y), wrapping around the tile.
    pub(crate) fn at(&self, x: usize, y: usize) -> f32 {
        self.data[(y & MASK) * SIZE + (x & MASK)]
    }
}

/// Normalised Gaussian taps with standard deviation `sigma`, out to 3 sigma.
fn gaussian_kernel(sigma: f64) -> Vec<f32> {
    let half = (3.0 * sigma).ceil() as i64;
    let taps: Vec<f64> = (-half..=half)
        .map(|k| (-0.5 * (k as f64 / sigma).powi(2)).exp())
        .collect();
    let sum: f64 = taps.iter().sum();
    taps.iter().map(|t| (t / sum) as f32).collect()
}

/// Circular convolution of every row with `kernel` (centred).
fn blur_rows(field: &mut [f32], kernel: &[f32]) {
    let half = kernel.len() / 2;
    let mut out = vec![0f32; SIZE];
    for row in field.chunks_exact_mut(SIZE) {
        for (x, o) in out.iter_mut().enumerate() {
            *o = kernel
                .iter()
                .enumerate()
                .map(|(k, w)| w * row[(x + SIZE + k - half) & MASK])
                .sum();
        }
        row.copy_from_slice(&out);
    }
}

fn transpose(field: &mut [f32]) {
    for y in 0..SIZE {
        for x in y + 1..SIZE {
            field.swap(y * SIZE + x, x * SIZE + y);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tile_has_speckle_statistics() {
        let tile = SpeckleTile::new(2.5, 1);
        let n = tile.data.len() as f64;
        let mean = tile.data.iter().map(|&v| f64::from(v)).sum::<f64>() / n;
        let var = tile
            .data
            .iter()
            .map(|&v| (f64::from(v) - mean).powi(2))
            .sum::<f64>()
            / n;
        // Fully developed speckle: contrast (std / mean) close to 1.
        assert!((mean - 1.0).abs() < 1e-3);
        assert!((var.sqrt() - 1.0).abs() < 0.15, "contrast {}", var.sqrt());
        // Grains span several pixels: neighbours are strongly correlated.
        let lag1 = (0..SIZE * SIZE)
            .map(|i| {
                (f64::from(tile.at(i, i / SIZE)) - mean)
                    * (f64::from(tile.at(i + 1, i / SIZE)) - mean)
            })
            .sum::<f64>()
            / n
            / var;
        assert!(lag1 > 0.5, "lag-1 correlation {lag1}");
        // The tile wraps.
        assert_eq!(tile.at(SIZE + 3, 5), tile.at(3, SIZE + 5 + SIZE));
    }
}
