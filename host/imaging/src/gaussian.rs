//! Fitting a round Gaussian spot to a bright region: `ln v = a + b·x + c·y + d·(x² + y²)` is
//! linear, so least squares on the visible part gives centre and radius even for a cut spot.

use super::tuning::MIN_GAUSSIAN_PIXELS;
use nalgebra::{Matrix4, Vector4};

/// A round Gaussian fitted to a region.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct GaussianFit {
    /// Centre, px (x right, y down); may lie outside the image for a clipped spot.
    pub centre: [f64; 2],
    /// 1/e² intensity radius, px.
    pub radius: f64,
    /// Peak level above the background.
    pub peak: f64,
    /// RMS misfit beyond the read noise, share of the peak: over a few per cent, not one spot.
    pub misfit: f64,
}

/// Collects pixels (about an origin, in `scale` px units: well conditioned) and solves the fit.
pub struct GaussianFitter {
    origin: [f64; 2],
    scale: f64,
    normal: Matrix4<f64>,
    rhs: Vector4<f64>,
    /// Σ w·y², for the residual.
    weighted_square: f64,
    count: usize,
}

impl GaussianFitter {
    pub fn new(origin: [f64; 2], scale: f64) -> Self {
        Self {
            origin,
            scale: scale.max(1.0),
            normal: Matrix4::zeros(),
            rhs: Vector4::zeros(),
            weighted_square: 0.0,
            count: 0,
        }
    }

    /// Adds a pixel of positive `value`; the weight `value²` makes the log fit a linear-space one.
    pub fn add(&mut self, point: [f64; 2], value: f64) {
        let [u, v] = [0, 1].map(|a| (point[a] - self.origin[a]) / self.scale);
        let row = Vector4::new(1.0, u, v, u * u + v * v);
        let (weight, target) = (value * value, value.ln());
        self.normal += row * row.transpose() * weight;
        self.rhs += row * (weight * target);
        self.weighted_square += weight * target * target;
        self.count += 1;
    }

    /// The fitted spot for read noise `noise`, gray levels; `None` if too few pixels or not peaked.
    pub fn finish(&self, noise: f64) -> Option<GaussianFit> {
        if self.count < MIN_GAUSSIAN_PIXELS {
            return None;
        }
        let solution = self.normal.cholesky()?.solve(&self.rhs);
        let [a, b, c, d] = [solution[0], solution[1], solution[2], solution[3]];
        if d >= 0.0 || d.is_nan() {
            return None;
        }
        let offset = [b, c].map(|k| -k / (2.0 * d));
        let peak = (a - d * (offset[0] * offset[0] + offset[1] * offset[1])).exp();
        let residual = (self.weighted_square - solution.dot(&self.rhs)).max(0.0);
        let fit = GaussianFit {
            centre: [0, 1].map(|i| self.origin[i] + offset[i] * self.scale),
            radius: (-2.0 / d).sqrt() * self.scale,
            peak,
            misfit: (residual / self.count as f64 - noise * noise)
                .max(0.0)
                .sqrt()
                / peak,
        };
        (fit.centre.iter().all(|c| c.is_finite()) && fit.peak.is_finite()).then_some(fit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot(x: f64, y: f64, centre: [f64; 2], radius: f64) -> f64 {
        let r2 = (x - centre[0]).powi(2) + (y - centre[1]).powi(2);
        150.0 * (-2.0 * r2 / radius.powi(2)).exp()
    }

    /// Fits the pixels of a 1920 x 1080 image above a floor, for spots given as a function.
    fn fit_visible(field: impl Fn(f64, f64) -> f64) -> Option<GaussianFit> {
        let mut fitter = GaussianFitter::new([960.0, 540.0], 100.0);
        for y in 0..1080 {
            for x in 0..1920 {
                let (px, py) = (f64::from(x) + 0.5, f64::from(y) + 0.5);
                let value = field(px, py);
                if value > 15.0 {
                    fitter.add([px, py], value);
                }
            }
        }
        fitter.finish(0.0)
    }

    #[test]
    fn recovers_a_whole_spot() {
        let fit = fit_visible(|x, y| spot(x, y, [700.3, 400.8], 120.0)).unwrap();
        assert!((fit.centre[0] - 700.3).abs() < 0.01 && (fit.centre[1] - 400.8).abs() < 0.01);
        assert!((fit.radius - 120.0).abs() < 0.01 && (fit.peak - 150.0).abs() < 0.01);
        assert!(fit.misfit < 1e-6, "{fit:?}");
    }

    #[test]
    fn recovers_the_centre_of_a_spot_cut_by_the_border() {
        let fit = fit_visible(|x, y| spot(x, y, [1000.0, -60.0], 130.0)).unwrap();
        assert!(
            (fit.centre[0] - 1000.0).abs() < 0.01 && (fit.centre[1] + 60.0).abs() < 0.01,
            "{fit:?}"
        );
    }

    #[test]
    fn two_merged_spots_fit_badly() {
        let fit = fit_visible(|x, y| {
            spot(x, y, [800.0, 500.0], 120.0) + spot(x, y, [1010.0, 520.0], 120.0)
        })
        .unwrap();
        assert!(fit.misfit > 0.05, "{fit:?}");
    }
}
