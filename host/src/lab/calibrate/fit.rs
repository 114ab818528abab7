//! The fits behind bench calibration: a least-squares affine map from two motor axes to an
//! image position, and a linear response with a dead band (backlash) fitted from the
//! hysteresis of the beam position.

use nalgebra::{DMatrix, DVector};

/// `position ≈ centre + matrix · (steps - reference)`, fitted by least squares.
#[derive(Clone, Debug, PartialEq)]
pub struct AffineFit {
    pub reference: [f64; 2],
    pub centre: [f64; 2],
    pub matrix: [[f64; 2]; 2],
    pub residual_rms: f64,
    /// Points fitted.
    pub points: usize,
    /// The inverse of the steps' scatter matrix `Σ (s - s̄)(s - s̄)ᵀ`: times a position
    /// variance, the covariance of each image coordinate's two slopes.
    pub inverse_scatter: [[f64; 2]; 2],
}

/// `centre + matrix · (steps - reference)`.
pub fn apply_affine(
    centre: [f64; 2],
    matrix: &[[f64; 2]; 2],
    reference: [f64; 2],
    steps: [f64; 2],
) -> [f64; 2] {
    let d = [steps[0] - reference[0], steps[1] - reference[1]];
    [
        centre[0] + matrix[0][0] * d[0] + matrix[0][1] * d[1],
        centre[1] + matrix[1][0] * d[0] + matrix[1][1] * d[1],
    ]
}

impl AffineFit {
    /// The fitted position at `steps`.
    pub fn predict(&self, steps: [f64; 2]) -> [f64; 2] {
        apply_affine(self.centre, &self.matrix, self.reference, steps)
    }

    /// For position errors of `sigma_px` per coordinate, the typical length of each axis's
    /// response (a column of the matrix, px per step) if that axis moved nothing: the
    /// RMS length of a column of pure noise.
    pub fn column_standard_error(&self, sigma_px: f64) -> [f64; 2] {
        [0, 1].map(|k| sigma_px * (2.0 * self.inverse_scatter[k][k]).sqrt())
    }

    /// Ratio of the matrix's larger singular value to its smaller (infinite when singular):
    /// how nearly the two axes move the beam along one line.
    pub fn condition_number(&self) -> f64 {
        let singular = nalgebra::Matrix2::new(
            self.matrix[0][0],
            self.matrix[0][1],
            self.matrix[1][0],
            self.matrix[1][1],
        )
        .singular_values();
        let (large, small) = (singular.max(), singular.min());
        if small > 0.0 {
            large / small
        } else {
            f64::INFINITY
        }
    }
}

/// Fits the affine map; needs at least three points not on a line.
pub fn fit_affine(steps: &[[f64; 2]], positions: &[[f64; 2]]) -> Option<AffineFit> {
    let n = steps.len();
    if n < 3 || positions.len() != n {
        return None;
    }
    let reference = [0, 1].map(|k| steps.iter().map(|s| s[k]).sum::<f64>() / n as f64);
    let design = DMatrix::from_fn(n, 3, |row, col| match col {
        0 => 1.0,
        k => steps[row][k - 1] - reference[k - 1],
    });
    let svd = design.clone().svd(true, true);
    if svd.singular_values.iter().any(|&s| s < 1e-9) {
        return None;
    }
    let mut scatter = nalgebra::Matrix2::zeros();
    for s in steps {
        let d = nalgebra::Vector2::new(s[0] - reference[0], s[1] - reference[1]);
        scatter += d * d.transpose();
    }
    let inverse = scatter.try_inverse()?;
    let mut coefficients = [[0.0; 3]; 2];
    let mut squared = 0.0;
    for (axis, row) in coefficients.iter_mut().enumerate() {
        let target = DVector::from_iterator(n, positions.iter().map(|p| p[axis]));
        let solution = svd.solve(&target, 1e-12).ok()?;
        squared += (&design * &solution - &target).norm_squared();
        row.copy_from_slice(solution.as_slice());
    }
    Some(AffineFit {
        reference,
        centre: [coefficients[0][0], coefficients[1][0]],
        matrix: [
            [coefficients[0][1], coefficients[0][2]],
            [coefficients[1][1], coefficients[1][2]],
        ],
        residual_rms: (squared / n as f64).sqrt(),
        points: n,
        inverse_scatter: [
            [inverse[(0, 0)], inverse[(0, 1)]],
            [inverse[(1, 0)], inverse[(1, 1)]],
        ],
    })
}

/// Load positions of a geared axis driven through `commands` (motor positions, in order),
/// with a dead band of `backlash` steps, starting pressed against the positive side.
pub fn play_operator(commands: &[f64], backlash: f64) -> Vec<f64> {
    let mut load = commands.first().copied().unwrap_or(0.0);
    commands
        .iter()
        .map(|&motor| {
            if motor > load {
                load = motor;
            } else if motor < load - backlash {
                load = motor + backlash;
            }
            load
        })
        .collect()
}

/// A linear response with a dead band: `position ≈ offset + gain · load(commands; B)`.
#[derive(Clone, Debug, PartialEq)]
pub struct BacklashFit {
    pub backlash: f64,
    /// One-standard-error uncertainty of `backlash` (where the residual sum of squares
    /// rises by one noise variance).
    pub uncertainty: f64,
    pub gain: f64,
    pub offset: f64,
    pub residual_rms: f64,
}

fn linear_fit(x: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = x.len() as f64;
    let (mx, my) = (x.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let sxx: f64 = x.iter().map(|v| (v - mx).powi(2)).sum();
    let sxy: f64 = x.iter().zip(y).map(|(a, b)| (a - mx) * (b - my)).sum();
    let gain = if sxx > 0.0 { sxy / sxx } else { 0.0 };
    let offset = my - gain * mx;
    let rss = x
        .iter()
        .zip(y)
        .map(|(a, b)| (b - offset - gain * a).powi(2))
        .sum();
    (gain, offset, rss)
}

/// Fits the dead band by scanning candidate widths in `resolution` steps up to `max`.
pub fn fit_backlash(
    commands: &[f64],
    positions: &[f64],
    max: f64,
    resolution: f64,
) -> Option<BacklashFit> {
    if commands.len() < 6 || positions.len() != commands.len() || max <= 0.0 || resolution <= 0.0 {
        return None;
    }
    let candidates: Vec<f64> = (0..=(max / resolution).ceil() as usize)
        .map(|i| i as f64 * resolution)
        .collect();
    let fits: Vec<(f64, (f64, f64, f64))> = candidates
        .iter()
        .map(|&b| (b, linear_fit(&play_operator(commands, b), positions)))
        .collect();
    let (backlash, (gain, offset, rss)) = *fits.iter().min_by(|a, b| a.1.2.total_cmp(&b.1.2))?;
    let noise = rss / (commands.len() as f64 - 3.0).max(1.0);
    let within: Vec<f64> = fits
        .iter()
        .filter(|(_, fit)| fit.2 <= rss + noise)
        .map(|(b, _)| *b)
        .collect();
    let spread = within
        .iter()
        .map(|b| (b - backlash).abs())
        .fold(0.0, f64::max);
    Some(BacklashFit {
        backlash,
        uncertainty: spread.max(resolution / 2.0),
        gain,
        offset,
        residual_rms: (rss / commands.len() as f64).sqrt(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn affine_fit_recovers_a_known_map() {
        let truth = |s: [f64; 2]| {
            [
                100.0 + 0.17 * s[0] + 0.012 * s[1],
                50.0 - 0.01 * s[0] - 0.16 * s[1],
            ]
        };
        let steps: Vec<[f64; 2]> = [-1000.0, 0.0, 1000.0]
            .iter()
            .flat_map(|&a| [-800.0, 0.0, 800.0].map(|b| [a, b]))
            .collect();
        let positions: Vec<[f64; 2]> = steps.iter().map(|&s| truth(s)).collect();
        let fit = fit_affine(&steps, &positions).unwrap();
        assert!((fit.matrix[0][0] - 0.17).abs() < 1e-9 && (fit.matrix[1][1] + 0.16).abs() < 1e-9);
        assert!((fit.matrix[0][1] - 0.012).abs() < 1e-9 && (fit.matrix[1][0] + 0.01).abs() < 1e-9);
        assert!(fit.residual_rms < 1e-9);
        assert!((fit.condition_number() - 1.0).abs() < 0.2);
        // Nine points 1000 and 800 steps apart: the slope of one coordinate on axis 1 is
        // known to sigma / sqrt(6 * 1000^2); the column's length to sqrt(2) times that.
        let se = fit.column_standard_error(1.0);
        assert!((se[0] - (2.0f64 / 6e6).sqrt()).abs() < 1e-12, "{se:?}");
        assert!(
            fit_affine(&steps[..2], &positions[..2]).is_none(),
            "too few points"
        );
        let line: Vec<[f64; 2]> = (0..5).map(|i| [i as f64, 2.0 * i as f64]).collect();
        assert!(
            fit_affine(&line, &positions[..5]).is_none(),
            "collinear points"
        );
    }

    #[test]
    fn play_operator_lags_by_the_dead_band_after_a_reversal() {
        let loads = play_operator(&[0.0, 10.0, 20.0, 15.0, 5.0, 0.0, 10.0], 8.0);
        assert_eq!(loads, vec![0.0, 10.0, 20.0, 20.0, 13.0, 8.0, 10.0]);
    }

    #[test]
    fn backlash_fit_recovers_the_dead_band() {
        let commands: Vec<f64> = (0..=20)
            .chain((-20..20).rev())
            .chain(-20..=20)
            .map(|i| f64::from(i) * 20.0)
            .collect();
        let loads = play_operator(&commands, 60.0);
        let positions: Vec<f64> = loads
            .iter()
            .enumerate()
            .map(|(i, l)| 3.0 + 0.05 * l + 0.05 * ((i * 7919) % 13) as f64 / 13.0)
            .collect();
        let fit = fit_backlash(&commands, &positions, 200.0, 1.0).unwrap();
        assert!((fit.backlash - 60.0).abs() <= 3.0, "{fit:?}");
        assert!((fit.gain - 0.05).abs() < 0.002);
        assert!(fit.uncertainty < 10.0);
    }
}
