//! The Matérn-5/2 covariance with one length scale per input axis (automatic relevance
//! determination) and a signal variance, with the derivatives the marginal-likelihood fit
//! needs.

const SQRT5: f64 = 2.236_067_977_499_79;

/// k(a, b) = s² (1 + √5 r + 5 r² / 3) exp(-√5 r), r² = Σ_j ((a_j - b_j) / ℓ_j)².
#[derive(Clone, Debug, PartialEq)]
pub struct Matern52 {
    pub length_scales: Vec<f64>,
    pub signal_variance: f64,
}

impl Matern52 {
    pub fn new(length_scales: Vec<f64>, signal_variance: f64) -> Self {
        Self {
            length_scales,
            signal_variance,
        }
    }

    /// Number of input axes.
    pub fn dims(&self) -> usize {
        self.length_scales.len()
    }

    /// The squared scaled distance r² between two inputs.
    pub fn scaled_distance2(&self, a: &[f64], b: &[f64]) -> f64 {
        let mut r2 = 0.0;
        for j in 0..self.length_scales.len() {
            let t = (a[j] - b[j]) / self.length_scales[j];
            r2 += t * t;
        }
        r2
    }

    /// The covariance of two inputs.
    pub fn value(&self, a: &[f64], b: &[f64]) -> f64 {
        self.of_distance2(self.scaled_distance2(a, b))
    }

    /// The covariance as a function of r².
    pub fn of_distance2(&self, r2: f64) -> f64 {
        self.value_and_slope(r2).0
    }

    /// The covariance at r² and its slope s = -2 dk/d(r²), from which the derivative with
    /// respect to log ℓ_j is s d_j² / ℓ_j² (d_j the difference on axis j), because
    /// d(r²)/d(log ℓ_j) = -2 d_j² / ℓ_j². The derivative with respect to the log signal
    /// variance is the covariance itself.
    ///
    /// dk/d(r²) = -(5/6) s² (1 + √5 r) exp(-√5 r), so s = (5/3) s² (1 + √5 r) exp(-√5 r).
    pub fn value_and_slope(&self, r2: f64) -> (f64, f64) {
        let r = r2.sqrt();
        let decay = (-SQRT5 * r).exp();
        let value = self.signal_variance * (1.0 + SQRT5 * r + 5.0 / 3.0 * r2) * decay;
        let slope = 5.0 / 3.0 * self.signal_variance * (1.0 + SQRT5 * r) * decay;
        (value, slope)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_closed_form_and_is_the_signal_variance_at_zero_distance() {
        let k = Matern52::new(vec![0.5, 2.0], 1.7);
        assert!((k.value(&[0.3, 0.1], &[0.3, 0.1]) - 1.7).abs() < 1e-15);
        // r = sqrt((0.4 / 0.5)^2 + (1.0 / 2.0)^2) = sqrt(0.89)
        let r: f64 = 0.89f64.sqrt();
        let expected = 1.7 * (1.0 + SQRT5 * r + 5.0 / 3.0 * 0.89) * (-SQRT5 * r).exp();
        assert!((k.value(&[0.0, 0.0], &[0.4, 1.0]) - expected).abs() < 1e-14);
        assert!(k.value(&[0.0, 0.0], &[0.4, 1.0]) < k.value(&[0.0, 0.0], &[0.2, 0.5]));
    }

    #[test]
    fn length_gradient_matches_finite_differences() {
        let a = [0.1, 0.7, 0.4];
        let b = [0.5, 0.2, 0.45];
        let k = Matern52::new(vec![0.3, 0.8, 0.05], 1.3);
        let (_, slope) = k.value_and_slope(k.scaled_distance2(&a, &b));
        for j in 0..3 {
            let analytic = slope * ((a[j] - b[j]) / k.length_scales[j]).powi(2);
            let h: f64 = 1e-6;
            let mut up = k.clone();
            up.length_scales[j] *= h.exp();
            let mut down = k.clone();
            down.length_scales[j] *= (-h).exp();
            let numeric = (up.value(&a, &b) - down.value(&a, &b)) / (2.0 * h);
            assert!(
                (numeric - analytic).abs() < 1e-7,
                "axis {j}: {numeric} vs {analytic}"
            );
        }
    }
}
