//! The dense linear algebra a Gaussian process needs, on plain row-major slices: the
//! Cholesky factor of a symmetric positive-definite matrix, triangular solves, the inverse
//! and the log-determinant. Plain index loops keep it fast even in unoptimised test
//! builds, where generic library code is compiled without optimisation.

/// The lower-triangular Cholesky factor L of A = L Lᵀ (row-major, n x n; the strict upper
/// triangle is zero).
#[derive(Clone, Debug, PartialEq)]
pub struct Cholesky {
    n: usize,
    l: Vec<f64>,
}

impl Cholesky {
    /// Factors the symmetric matrix `a` (row-major n x n; only its lower triangle is read).
    /// `None` when it is not positive definite (or holds non-finite numbers).
    pub fn new(mut a: Vec<f64>, n: usize) -> Option<Self> {
        assert_eq!(a.len(), n * n, "a {n} x {n} matrix");
        for j in 0..n {
            let row_j = j * n;
            let mut diagonal = a[row_j + j];
            for k in 0..j {
                diagonal -= a[row_j + k] * a[row_j + k];
            }
            if !(diagonal > 0.0 && diagonal.is_finite()) {
                return None;
            }
            let pivot = diagonal.sqrt();
            a[row_j + j] = pivot;
            for i in j + 1..n {
                let row_i = i * n;
                let mut sum = a[row_i + j];
                for k in 0..j {
                    sum -= a[row_i + k] * a[row_j + k];
                }
                a[row_i + j] = sum / pivot;
            }
            for k in j + 1..n {
                a[row_j + k] = 0.0;
            }
        }
        Some(Self { n, l: a })
    }

    /// L[i][j].
    pub fn factor(&self, i: usize, j: usize) -> f64 {
        self.l[i * self.n + j]
    }

    /// Solves L v = b in place.
    pub fn solve_lower(&self, b: &mut [f64]) {
        let n = self.n;
        for i in 0..n {
            let row = i * n;
            let mut sum = b[i];
            for (l, v) in self.l[row..row + i].iter().zip(&b[..i]) {
                sum -= l * v;
            }
            b[i] = sum / self.l[row + i];
        }
    }

    /// Solves Lᵀ x = b in place.
    pub fn solve_upper(&self, b: &mut [f64]) {
        let n = self.n;
        for i in (0..n).rev() {
            let mut sum = b[i];
            for (k, v) in b.iter().enumerate().skip(i + 1) {
                sum -= self.l[k * n + i] * v;
            }
            b[i] = sum / self.l[i * n + i];
        }
    }

    /// Solves A x = b.
    pub fn solve(&self, b: &[f64]) -> Vec<f64> {
        let mut x = b.to_vec();
        self.solve_lower(&mut x);
        self.solve_upper(&mut x);
        x
    }

    /// ½ log det A = Σ log L_ii.
    pub fn half_log_det(&self) -> f64 {
        (0..self.n).map(|i| self.l[i * self.n + i].ln()).sum()
    }

    /// A⁻¹ (row-major n x n, both triangles) = L⁻ᵀ L⁻¹.
    pub fn inverse(&self) -> Vec<f64> {
        let n = self.n;
        // Row-major L⁻¹, lower triangular, one column at a time.
        let mut inv_l = vec![0.0; n * n];
        for c in 0..n {
            inv_l[c * n + c] = 1.0 / self.l[c * n + c];
            for i in c + 1..n {
                let row = i * n;
                let mut sum = 0.0;
                for k in c..i {
                    sum -= self.l[row + k] * inv_l[k * n + c];
                }
                inv_l[row + c] = sum / self.l[row + i];
            }
        }
        let mut inverse = vec![0.0; n * n];
        for a in 0..n {
            for b in 0..=a {
                let mut sum = 0.0;
                for k in a..n {
                    sum += inv_l[k * n + a] * inv_l[k * n + b];
                }
                inverse[a * n + b] = sum;
                inverse[b * n + a] = sum;
            }
        }
        inverse
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;

    /// A random symmetric positive-definite matrix B Bᵀ + n I.
    fn spd(n: usize, rng: &mut ChaCha8Rng) -> Vec<f64> {
        let b: Vec<f64> = (0..n * n).map(|_| rng.random_range(-1.0..1.0)).collect();
        let mut a = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                a[i * n + j] = (0..n).map(|k| b[i * n + k] * b[j * n + k]).sum::<f64>();
            }
            a[i * n + i] += n as f64;
        }
        a
    }

    #[test]
    fn the_factor_reproduces_the_matrix_and_solves_and_inverts_it() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 9;
        let a = spd(n, &mut rng);
        let chol = Cholesky::new(a.clone(), n).unwrap();
        for i in 0..n {
            for j in 0..n {
                let product: f64 = (0..n).map(|k| chol.factor(i, k) * chol.factor(j, k)).sum();
                assert!((product - a[i * n + j]).abs() < 1e-12, "({i}, {j})");
                if j > i {
                    assert_eq!(chol.factor(i, j), 0.0);
                }
            }
        }
        let b: Vec<f64> = (0..n).map(|i| i as f64 - 3.0).collect();
        let x = chol.solve(&b);
        for i in 0..n {
            let ax: f64 = (0..n).map(|k| a[i * n + k] * x[k]).sum();
            assert!((ax - b[i]).abs() < 1e-12);
        }
        let inverse = chol.inverse();
        for i in 0..n {
            for j in 0..n {
                let product: f64 = (0..n).map(|k| a[i * n + k] * inverse[k * n + j]).sum();
                let identity = if i == j { 1.0 } else { 0.0 };
                assert!((product - identity).abs() < 1e-12, "({i}, {j})");
            }
        }
        // det [[4, 2], [2, 3]] = 8.
        let small = Cholesky::new(vec![4.0, 2.0, 2.0, 3.0], 2).unwrap();
        assert!((small.half_log_det() - 0.5 * 8f64.ln()).abs() < 1e-15);
    }

    #[test]
    fn indefinite_and_non_finite_matrices_are_refused() {
        assert!(Cholesky::new(vec![1.0, 2.0, 2.0, 1.0], 2).is_none());
        assert!(Cholesky::new(vec![f64::NAN, 0.0, 0.0, 1.0], 2).is_none());
        assert!(Cholesky::new(vec![0.0], 1).is_none());
    }
}
