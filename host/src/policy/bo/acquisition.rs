//! Expected improvement, and its maximisation over the unit box: random candidates plus
//! perturbations of the incumbent, the best few refined by compass search.

use optalign_optics::normal_cdf;
use rand::Rng;

use super::gp::GaussianProcess;
use super::optimise::compass_search;

/// The exploration margin of the paper's expected improvement, on the GP's standardised
/// output scale (a hundredth of the objective's spread over the observations).
pub const XI: f64 = 0.01;

/// How the acquisition function is searched.
#[derive(Clone, Debug, PartialEq)]
pub struct AcquisitionSearch {
    /// Uniform random candidates in the unit box.
    pub random_candidates: usize,
    /// Gaussian perturbations of the incumbent (standard deviation `local_spread`).
    pub local_candidates: usize,
    pub local_spread: f64,
    /// Best candidates refined by compass search.
    pub refined: usize,
}

impl Default for AcquisitionSearch {
    fn default() -> Self {
        Self {
            random_candidates: 1000,
            local_candidates: 200,
            local_spread: 0.05,
            refined: 3,
        }
    }
}

/// Expected improvement over `best` of a normal prediction (mean, standard deviation),
/// for maximisation: E[max(f - best - xi, 0)].
pub fn expected_improvement(mean: f64, std: f64, best: f64, xi: f64) -> f64 {
    let gain = mean - best - xi;
    if std <= 1e-12 {
        return gain.max(0.0);
    }
    let z = gain / std;
    (gain * normal_cdf(z) + std * normal_pdf(z)).max(0.0)
}

/// The standard normal density.
pub fn normal_pdf(z: f64) -> f64 {
    (-0.5 * z * z).exp() / (2.0 * std::f64::consts::PI).sqrt()
}

/// Expected improvement of the GP at `x` over the best standardised observation.
pub fn gp_expected_improvement(gp: &GaussianProcess, x: &[f64], best_standardised: f64) -> f64 {
    let p = gp.predict_standardised(x);
    expected_improvement(p.mean, p.variance.sqrt(), best_standardised, XI)
}

/// The point of the unit box with the highest expected improvement found, and its value.
pub fn maximise_expected_improvement(
    gp: &GaussianProcess,
    best_standardised: f64,
    incumbent: &[f64],
    search: &AcquisitionSearch,
    rng: &mut impl Rng,
) -> (Vec<f64>, f64) {
    let dims = incumbent.len();
    let ei = |x: &[f64]| gp_expected_improvement(gp, x, best_standardised);
    let mut scored: Vec<(Vec<f64>, f64)> =
        Vec::with_capacity(search.random_candidates + search.local_candidates);
    for _ in 0..search.random_candidates {
        let x: Vec<f64> = (0..dims).map(|_| rng.random::<f64>()).collect();
        let value = ei(&x);
        scored.push((x, value));
    }
    for _ in 0..search.local_candidates {
        let x: Vec<f64> = incumbent
            .iter()
            .map(|c| (c + search.local_spread * standard_normal(rng)).clamp(0.0, 1.0))
            .collect();
        let value = ei(&x);
        scored.push((x, value));
    }
    scored.sort_by(|a, b| b.1.total_cmp(&a.1));
    scored
        .into_iter()
        .take(search.refined.max(1))
        .map(|(x, value)| compass_search(ei, x, value, 0.05, 1e-3, 60 * dims))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .unwrap_or_else(|| (incumbent.to_vec(), 0.0))
}

/// A standard normal draw (Box–Muller).
fn standard_normal(rng: &mut impl Rng) -> f64 {
    let u: f64 = rng.random_range(f64::EPSILON..1.0);
    let v: f64 = rng.random();
    (-2.0 * u.ln()).sqrt() * (2.0 * std::f64::consts::PI * v).cos()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn expected_improvement_has_its_defining_properties() {
        // Never negative, even far below the best.
        assert!(expected_improvement(-10.0, 0.1, 0.0, XI) >= 0.0);
        // At mean = best + xi it is std x φ(0).
        let at_par = expected_improvement(1.0 + XI, 0.5, 1.0, XI);
        assert!((at_par - 0.5 / (2.0 * std::f64::consts::PI).sqrt()).abs() < 1e-9);
        // Without uncertainty it is the plain improvement beyond xi.
        assert!((expected_improvement(2.0, 0.0, 1.0, XI) - (1.0 - XI)).abs() < 1e-15);
        assert_eq!(expected_improvement(0.5, 0.0, 1.0, XI), 0.0);
        // Rises with the mean and with the uncertainty.
        let means = [-2.0, -0.5, 0.0, 0.3, 1.0, 3.0];
        for pair in means.windows(2) {
            assert!(
                expected_improvement(pair[1], 0.4, 0.0, XI)
                    > expected_improvement(pair[0], 0.4, 0.0, XI)
            );
        }
        let stds = [0.05, 0.2, 0.6, 1.0, 2.5];
        for mean in &means[1..5] {
            for pair in stds.windows(2) {
                assert!(
                    expected_improvement(*mean, pair[1], 0.0, XI)
                        > expected_improvement(*mean, pair[0], 0.0, XI),
                    "mean {mean}, std {pair:?}"
                );
            }
        }
        // Matches E[max(f - best - xi, 0)] by quadrature.
        let (mean, std, best) = (0.2, 0.7, 0.5);
        let steps = 200_000;
        let quadrature: f64 = (0..steps)
            .map(|i| {
                let z = -10.0 + 20.0 * (i as f64 + 0.5) / steps as f64;
                (mean + std * z - best - XI).max(0.0) * normal_pdf(z) * 20.0 / steps as f64
            })
            .sum();
        assert!((expected_improvement(mean, std, best, XI) - quadrature).abs() < 1e-6);
    }
}
