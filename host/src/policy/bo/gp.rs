//! A Gaussian-process regressor with a Matérn-5/2 ARD kernel on inputs in the unit box.
//! Outputs are standardised to zero mean and unit variance; the hyperparameters (one length
//! scale per axis, the signal variance, the noise variance) are fitted by maximising the
//! log marginal likelihood with multi-start L-BFGS on a bounded reparametrisation, using
//! the analytic gradient.

use nalgebra::{Cholesky, DMatrix, DVector, Dyn};
use rand::Rng;

use super::kernel::Matern52;
use super::optimise::lbfgs;

/// Bounds of the fitted hyperparameters, for inputs in [0, 1] and standardised outputs.
pub const LENGTH_SCALE_BOUNDS: (f64, f64) = (0.01, 10.0);
pub const SIGNAL_VARIANCE_BOUNDS: (f64, f64) = (0.05, 20.0);
pub const NOISE_VARIANCE_BOUNDS: (f64, f64) = (1e-6, 0.5);

/// L-BFGS iterations per start of the likelihood fit.
const FIT_ITERATIONS: usize = 60;

const LN_2PI: f64 = 1.837_877_066_409_345_5;

/// The kernel's and the noise's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct Hyperparameters {
    pub length_scales: Vec<f64>,
    pub signal_variance: f64,
    pub noise_variance: f64,
}

impl Hyperparameters {
    /// The starting guess of every fit: length 0.3 on each axis, unit signal, small noise.
    pub fn default_for(dims: usize) -> Self {
        Self {
            length_scales: vec![0.3; dims],
            signal_variance: 1.0,
            noise_variance: 1e-3,
        }
    }

    /// The bounds of each entry of the unconstrained vector, in its order.
    fn bounds(dims: usize) -> impl Iterator<Item = (f64, f64)> {
        std::iter::repeat_n(LENGTH_SCALE_BOUNDS, dims)
            .chain([SIGNAL_VARIANCE_BOUNDS, NOISE_VARIANCE_BOUNDS])
    }

    /// The unconstrained vector z with value = exp(lo + (hi - lo) sigmoid(z)) in log space.
    fn to_unconstrained(&self) -> Vec<f64> {
        let values = self
            .length_scales
            .iter()
            .copied()
            .chain([self.signal_variance, self.noise_variance]);
        values
            .zip(Self::bounds(self.length_scales.len()))
            .map(|(value, (lo, hi))| {
                let (lo, hi) = (lo.ln(), hi.ln());
                let p = ((value.ln() - lo) / (hi - lo)).clamp(1e-6, 1.0 - 1e-6);
                (p / (1.0 - p)).ln()
            })
            .collect()
    }

    /// The parameters of an unconstrained vector, and d(log value)/dz for each entry.
    fn from_unconstrained(z: &[f64]) -> (Self, Vec<f64>) {
        let dims = z.len() - 2;
        let mut values = Vec::with_capacity(z.len());
        let mut slopes = Vec::with_capacity(z.len());
        for (zi, (lo, hi)) in z.iter().zip(Self::bounds(dims)) {
            let (lo, hi) = (lo.ln(), hi.ln());
            let p = 1.0 / (1.0 + (-zi).exp());
            values.push((lo + (hi - lo) * p).exp());
            slopes.push((hi - lo) * p * (1.0 - p));
        }
        let hyper = Self {
            length_scales: values[..dims].to_vec(),
            signal_variance: values[dims],
            noise_variance: values[dims + 1],
        };
        (hyper, slopes)
    }
}

/// Why a GP could not be built.
#[derive(Debug, thiserror::Error)]
pub enum GpError {
    #[error("a Gaussian process needs at least one observation")]
    NoData,
    #[error("inputs must all have {expected} coordinates; one has {got}")]
    Dimensions { expected: usize, got: usize },
    #[error("observations must be finite numbers")]
    NonFinite,
    #[error("the covariance matrix is not positive definite")]
    NotPositiveDefinite,
}

/// A posterior prediction of the latent function (no observation noise).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Prediction {
    pub mean: f64,
    pub variance: f64,
}

/// A GP conditioned on observations.
pub struct GaussianProcess {
    inputs: Vec<Vec<f64>>,
    kernel: Matern52,
    noise_variance: f64,
    output_mean: f64,
    output_scale: f64,
    cholesky: Cholesky<f64, Dyn>,
    /// K⁻¹ y on the standardised outputs.
    weights: DVector<f64>,
    log_marginal_likelihood: f64,
}

impl GaussianProcess {
    /// Conditions a GP with the given hyperparameters on `(inputs, outputs)`.
    pub fn condition(
        inputs: Vec<Vec<f64>>,
        outputs: &[f64],
        hyper: &Hyperparameters,
    ) -> Result<Self, GpError> {
        let data = Standardised::new(&inputs, outputs)?;
        let kernel = Matern52::new(hyper.length_scales.clone(), hyper.signal_variance);
        let covariance = covariance(&inputs, &kernel, hyper.noise_variance);
        let cholesky = factor(covariance).ok_or(GpError::NotPositiveDefinite)?;
        let weights = cholesky.solve(&DVector::from_column_slice(&data.values));
        let log_marginal_likelihood = log_likelihood(&cholesky, &data.values, weights.as_slice());
        Ok(Self {
            inputs,
            kernel,
            noise_variance: hyper.noise_variance,
            output_mean: data.mean,
            output_scale: data.scale,
            cholesky,
            weights,
            log_marginal_likelihood,
        })
    }

    /// Fits the hyperparameters by maximum marginal likelihood, starting L-BFGS from
    /// `warm_start` (or the default guess) and from `random_starts` random points; then
    /// conditions on the data with the best.
    pub fn fit(
        inputs: Vec<Vec<f64>>,
        outputs: &[f64],
        warm_start: Option<&Hyperparameters>,
        random_starts: usize,
        rng: &mut impl Rng,
    ) -> Result<Self, GpError> {
        let data = Standardised::new(&inputs, outputs)?;
        let dims = inputs[0].len();
        let pairs = PairDifferences::new(&inputs);
        let first = warm_start
            .cloned()
            .unwrap_or_else(|| Hyperparameters::default_for(dims));
        let mut starts = vec![first.to_unconstrained()];
        for _ in 0..random_starts {
            starts.push((0..dims + 2).map(|_| rng.random_range(-2.5..2.5)).collect());
        }
        let best = starts
            .into_iter()
            .map(|z| {
                lbfgs(
                    |z, gradient| negative_log_likelihood(&pairs, &data.values, z, gradient),
                    z,
                    FIT_ITERATIONS,
                )
            })
            .filter(|minimum| minimum.value.is_finite())
            .min_by(|a, b| a.value.total_cmp(&b.value))
            .ok_or(GpError::NotPositiveDefinite)?;
        let (hyper, _) = Hyperparameters::from_unconstrained(&best.x);
        Self::condition(inputs, outputs, &hyper)
    }

    pub fn hyperparameters(&self) -> Hyperparameters {
        Hyperparameters {
            length_scales: self.kernel.length_scales.clone(),
            signal_variance: self.kernel.signal_variance,
            noise_variance: self.noise_variance,
        }
    }

    /// Log marginal likelihood of the standardised outputs under the hyperparameters.
    pub fn log_marginal_likelihood(&self) -> f64 {
        self.log_marginal_likelihood
    }

    /// Maps an output to the standardised scale the GP works on.
    pub fn standardise(&self, output: f64) -> f64 {
        (output - self.output_mean) / self.output_scale
    }

    /// The posterior of the latent function at `x`, on the standardised scale.
    pub fn predict_standardised(&self, x: &[f64]) -> Prediction {
        let mut cross = DVector::from_iterator(
            self.inputs.len(),
            self.inputs.iter().map(|xi| self.kernel.value(x, xi)),
        );
        let mean = cross.dot(&self.weights);
        self.cholesky
            .l_dirty()
            .solve_lower_triangular_mut(&mut cross);
        let explained = cross.norm_squared();
        Prediction {
            mean,
            variance: (self.kernel.signal_variance - explained).max(0.0),
        }
    }

    /// The posterior of the latent function at `x`, in the outputs' units.
    pub fn predict(&self, x: &[f64]) -> Prediction {
        let standard = self.predict_standardised(x);
        Prediction {
            mean: self.output_mean + self.output_scale * standard.mean,
            variance: standard.variance * self.output_scale * self.output_scale,
        }
    }
}

/// Outputs shifted to zero mean and scaled to unit variance (scale 1 when all are equal).
struct Standardised {
    values: Vec<f64>,
    mean: f64,
    scale: f64,
}

impl Standardised {
    fn new(inputs: &[Vec<f64>], outputs: &[f64]) -> Result<Self, GpError> {
        let first = inputs.first().ok_or(GpError::NoData)?;
        if inputs.len() != outputs.len() {
            return Err(GpError::NoData);
        }
        if let Some(bad) = inputs.iter().find(|x| x.len() != first.len()) {
            return Err(GpError::Dimensions {
                expected: first.len(),
                got: bad.len(),
            });
        }
        if outputs
            .iter()
            .chain(inputs.iter().flatten())
            .any(|v| !v.is_finite())
        {
            return Err(GpError::NonFinite);
        }
        let n = outputs.len() as f64;
        let mean = outputs.iter().sum::<f64>() / n;
        let variance = outputs.iter().map(|y| (y - mean).powi(2)).sum::<f64>() / n;
        let scale = if variance.sqrt() > 1e-12 * (1.0 + mean.abs()) {
            variance.sqrt()
        } else {
            1.0
        };
        Ok(Self {
            values: outputs.iter().map(|y| (y - mean) / scale).collect(),
            mean,
            scale,
        })
    }
}

/// K + noise I, its lower triangle (all the Cholesky factor reads; each pair's kernel once).
fn covariance(inputs: &[Vec<f64>], kernel: &Matern52, noise_variance: f64) -> DMatrix<f64> {
    let n = inputs.len();
    DMatrix::from_fn(n, n, |a, b| match a.cmp(&b) {
        std::cmp::Ordering::Less => 0.0,
        std::cmp::Ordering::Equal => kernel.signal_variance + noise_variance,
        std::cmp::Ordering::Greater => kernel.value(&inputs[a], &inputs[b]),
    })
}

/// The Cholesky factor of a covariance matrix (only its lower triangle is read); `None`
/// when it is not positive definite or holds a number that is not finite.
fn factor(covariance: DMatrix<f64>) -> Option<Cholesky<f64, Dyn>> {
    if covariance.iter().all(|v| v.is_finite()) {
        Cholesky::new(covariance)
    } else {
        None
    }
}

fn log_likelihood(cholesky: &Cholesky<f64, Dyn>, y: &[f64], weights: &[f64]) -> f64 {
    let fit: f64 = y.iter().zip(weights).map(|(a, b)| a * b).sum();
    -0.5 * fit - 0.5 * cholesky.ln_determinant() - 0.5 * y.len() as f64 * LN_2PI
}

/// Squared differences of every pair of inputs per axis, which do not change while the
/// hyperparameters are fitted: pair (a, b < a) at `a (a - 1) / 2 + b`.
struct PairDifferences {
    n: usize,
    dims: usize,
    squared: Vec<f64>,
}

impl PairDifferences {
    fn new(inputs: &[Vec<f64>]) -> Self {
        let n = inputs.len();
        let dims = inputs.first().map_or(0, Vec::len);
        let mut squared = Vec::with_capacity(n * n.saturating_sub(1) / 2 * dims);
        for a in 0..n {
            for b in 0..a {
                for (x, y) in inputs[a].iter().zip(&inputs[b]) {
                    squared.push((x - y) * (x - y));
                }
            }
        }
        Self { n, dims, squared }
    }
}

/// Minus the log marginal likelihood at the unconstrained hyperparameters `z`, with its
/// gradient: d/dθ log p = ½ tr((α αᵀ - K⁻¹) dK/dθ) for each log parameter θ, times dθ/dz.
fn negative_log_likelihood(
    pairs: &PairDifferences,
    y: &[f64],
    z: &[f64],
    gradient: &mut [f64],
) -> f64 {
    let (hyper, slopes) = Hyperparameters::from_unconstrained(z);
    let (n, dims) = (pairs.n, pairs.dims);
    let kernel = Matern52::new(hyper.length_scales, hyper.signal_variance);
    let inverse_squares: Vec<f64> = kernel.length_scales.iter().map(|l| 1.0 / (l * l)).collect();
    let mut k = DMatrix::zeros(n, n);
    let mut pair_values = Vec::with_capacity(pairs.squared.len() / dims.max(1));
    let mut pair_slopes = Vec::with_capacity(pair_values.capacity());
    let mut p = 0;
    for a in 0..n {
        k[(a, a)] = kernel.signal_variance + hyper.noise_variance;
        for b in 0..a {
            let diffs = &pairs.squared[p * dims..(p + 1) * dims];
            let mut r2 = 0.0;
            for (d, w) in diffs.iter().zip(&inverse_squares) {
                r2 += d * w;
            }
            let (value, slope) = kernel.value_and_slope(r2);
            k[(a, b)] = value;
            pair_values.push(value);
            pair_slopes.push(slope);
            p += 1;
        }
    }
    let Some(cholesky) = factor(k) else {
        return f64::NAN;
    };
    let alpha = cholesky.solve(&DVector::from_column_slice(y));
    let likelihood = log_likelihood(&cholesky, y, alpha.as_slice());
    let inverse = cholesky.inverse();
    let mut d_length = vec![0.0; dims];
    let mut d_signal = 0.0;
    let mut d_noise = 0.0;
    let mut p = 0;
    for a in 0..n {
        let w_aa = alpha[a] * alpha[a] - inverse[(a, a)];
        d_signal += w_aa * kernel.signal_variance;
        d_noise += w_aa * hyper.noise_variance;
        for b in 0..a {
            let w_ab = 2.0 * (alpha[a] * alpha[b] - inverse[(a, b)]);
            d_signal += w_ab * pair_values[p];
            let scale = w_ab * pair_slopes[p];
            let diffs = &pairs.squared[p * dims..(p + 1) * dims];
            for ((g, d), w) in d_length.iter_mut().zip(diffs).zip(&inverse_squares) {
                *g += scale * d * w;
            }
            p += 1;
        }
    }
    let log_gradient = d_length.into_iter().chain([d_signal, d_noise]);
    for ((g, dlog), slope) in gradient.iter_mut().zip(log_gradient).zip(&slopes) {
        *g = -0.5 * dlog * slope;
    }
    -likelihood
}

#[cfg(test)]
mod tests {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;

    #[test]
    fn matches_the_analytic_posterior_of_two_observations() {
        let hyper = Hyperparameters {
            length_scales: vec![0.4],
            signal_variance: 1.5,
            noise_variance: 0.1,
        };
        let (x1, x2, xs) = (0.2, 0.5, 0.35);
        // Standardised outputs of (3, 7): mean 5, scale 2 -> (-1, 1).
        let gp = GaussianProcess::condition(vec![vec![x1], vec![x2]], &[3.0, 7.0], &hyper).unwrap();
        let k = Matern52::new(vec![0.4], 1.5);
        let (k11, k12) = (1.5 + 0.1, k.value(&[x1], &[x2]));
        let det = k11 * k11 - k12 * k12;
        let inv = [[k11 / det, -k12 / det], [-k12 / det, k11 / det]];
        let ks = [k.value(&[xs], &[x1]), k.value(&[xs], &[x2])];
        let y = [-1.0, 1.0];
        let w = [
            inv[0][0] * y[0] + inv[0][1] * y[1],
            inv[1][0] * y[0] + inv[1][1] * y[1],
        ];
        let mean = ks[0] * w[0] + ks[1] * w[1];
        let quad = ks[0] * (inv[0][0] * ks[0] + inv[0][1] * ks[1])
            + ks[1] * (inv[1][0] * ks[0] + inv[1][1] * ks[1]);
        let prediction = gp.predict(&[xs]);
        assert!((prediction.mean - (5.0 + 2.0 * mean)).abs() < 1e-12);
        assert!((prediction.variance - 4.0 * (1.5 - quad)).abs() < 1e-12);
        let lml = -0.5 * (y[0] * w[0] + y[1] * w[1]) - 0.5 * det.ln() - LN_2PI;
        assert!((gp.log_marginal_likelihood() - lml).abs() < 1e-12);
    }

    #[test]
    fn interpolates_noise_free_data_and_is_uncertain_far_from_it() {
        let inputs: Vec<Vec<f64>> = (0..6).map(|i| vec![i as f64 / 5.0, 0.5]).collect();
        let outputs: Vec<f64> = inputs.iter().map(|x| (6.0 * x[0]).sin()).collect();
        let hyper = Hyperparameters {
            noise_variance: 1e-6,
            ..Hyperparameters::default_for(2)
        };
        let gp = GaussianProcess::condition(inputs.clone(), &outputs, &hyper).unwrap();
        for (x, y) in inputs.iter().zip(&outputs) {
            let p = gp.predict(x);
            assert!((p.mean - y).abs() < 1e-3, "{x:?}: {} vs {y}", p.mean);
            assert!(p.variance < 1e-4);
        }
        assert!(gp.predict(&[0.5, 0.0]).variance > 100.0 * gp.predict(&[0.4, 0.5]).variance);
    }

    #[test]
    fn likelihood_gradient_matches_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        let inputs: Vec<Vec<f64>> = (0..9)
            .map(|_| vec![rng.random(), rng.random(), rng.random()])
            .collect();
        let y: Vec<f64> = inputs.iter().map(|x| x[0] * 2.0 - x[1].cos()).collect();
        let pairs = PairDifferences::new(&inputs);
        let z = vec![0.3, -0.8, 1.1, 0.2, -1.5];
        let mut gradient = vec![0.0; 5];
        negative_log_likelihood(&pairs, &y, &z, &mut gradient);
        let mut scratch = vec![0.0; 5];
        for i in 0..5 {
            let h = 1e-5;
            let mut up = z.clone();
            up[i] += h;
            let mut down = z.clone();
            down[i] -= h;
            let numeric = (negative_log_likelihood(&pairs, &y, &up, &mut scratch)
                - negative_log_likelihood(&pairs, &y, &down, &mut scratch))
                / (2.0 * h);
            assert!(
                (numeric - gradient[i]).abs() < 1e-5 * (1.0 + numeric.abs()),
                "entry {i}: {numeric} vs {}",
                gradient[i]
            );
        }
    }

    #[test]
    fn the_fit_finds_the_relevant_axis_and_raises_the_likelihood() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let inputs: Vec<Vec<f64>> = (0..30).map(|_| vec![rng.random(), rng.random()]).collect();
        // Varies along axis 0 only.
        let outputs: Vec<f64> = inputs.iter().map(|x| (5.0 * x[0]).sin()).collect();
        let start = Hyperparameters::default_for(2);
        let before = GaussianProcess::condition(inputs.clone(), &outputs, &start).unwrap();
        let fitted = GaussianProcess::fit(inputs, &outputs, None, 2, &mut rng).unwrap();
        let hyper = fitted.hyperparameters();
        assert!(fitted.log_marginal_likelihood() > before.log_marginal_likelihood());
        assert!(
            hyper.length_scales[1] > 5.0 * hyper.length_scales[0],
            "{hyper:?}"
        );
        let p = fitted.predict(&[0.3, 0.9]);
        assert!((p.mean - 1.5f64.sin()).abs() < 0.05, "{p:?}");
    }

    #[test]
    fn refuses_empty_ragged_and_non_finite_data() {
        let hyper = Hyperparameters::default_for(1);
        assert!(matches!(
            GaussianProcess::condition(vec![], &[], &hyper),
            Err(GpError::NoData)
        ));
        assert!(matches!(
            GaussianProcess::condition(vec![vec![0.1], vec![0.2, 0.3]], &[1.0, 2.0], &hyper),
            Err(GpError::Dimensions {
                expected: 1,
                got: 2
            })
        ));
        assert!(matches!(
            GaussianProcess::condition(vec![vec![0.1]], &[f64::NAN], &hyper),
            Err(GpError::NonFinite)
        ));
    }
}
