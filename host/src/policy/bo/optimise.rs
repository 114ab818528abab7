//! The two small optimisers Bayesian optimisation needs: L-BFGS with a backtracking line
//! search for the smooth hyperparameter likelihood, and a compass search in the unit box
//! for refining the acquisition function's maximum.

use std::collections::VecDeque;

/// Where a minimisation ended.
#[derive(Clone, Debug, PartialEq)]
pub struct Minimum {
    pub x: Vec<f64>,
    pub value: f64,
}

/// Curvature pairs L-BFGS remembers.
const MEMORY: usize = 7;

/// Minimises a smooth `f`, which writes its gradient into the second argument, from `x0`
/// with at most `max_iterations` quasi-Newton steps. Non-finite values count as worse than
/// any finite one, so a line search backs away from them.
pub fn lbfgs(
    mut f: impl FnMut(&[f64], &mut [f64]) -> f64,
    x0: Vec<f64>,
    max_iterations: usize,
) -> Minimum {
    let n = x0.len();
    let mut x = x0;
    let mut gradient = vec![0.0; n];
    let mut value = f(&x, &mut gradient);
    if !value.is_finite() || gradient.iter().any(|g| !g.is_finite()) {
        return Minimum { x, value };
    }
    let mut memory: VecDeque<(Vec<f64>, Vec<f64>, f64)> = VecDeque::with_capacity(MEMORY);
    let mut trial = vec![0.0; n];
    let mut trial_gradient = vec![0.0; n];
    for _ in 0..max_iterations {
        if gradient.iter().all(|g| g.abs() < 1e-7) {
            break;
        }
        let mut direction = two_loop(&memory, &gradient);
        let mut slope = dot(&gradient, &direction);
        if slope >= 0.0 {
            memory.clear();
            direction = two_loop(&memory, &gradient);
            slope = dot(&gradient, &direction);
        }
        let mut step = 1.0;
        let mut accepted = None;
        for _ in 0..40 {
            for ((t, xi), di) in trial.iter_mut().zip(&x).zip(&direction) {
                *t = xi + step * di;
            }
            let trial_value = f(&trial, &mut trial_gradient);
            if trial_value.is_finite()
                && trial_gradient.iter().all(|g| g.is_finite())
                && trial_value <= value + 1e-4 * step * slope
            {
                accepted = Some(trial_value);
                break;
            }
            step *= 0.5;
        }
        let Some(trial_value) = accepted else { break };
        let s: Vec<f64> = trial.iter().zip(&x).map(|(a, b)| a - b).collect();
        let y: Vec<f64> = trial_gradient
            .iter()
            .zip(&gradient)
            .map(|(a, b)| a - b)
            .collect();
        let curvature = dot(&s, &y);
        if curvature > 1e-12 {
            if memory.len() == MEMORY {
                memory.pop_front();
            }
            memory.push_back((s, y, 1.0 / curvature));
        }
        let decrease = value - trial_value;
        x.copy_from_slice(&trial);
        gradient.copy_from_slice(&trial_gradient);
        value = trial_value;
        if decrease <= 1e-10 * (1.0 + value.abs()) {
            break;
        }
    }
    Minimum { x, value }
}

/// The L-BFGS search direction -H g from the remembered curvature pairs; without any, a
/// steepest-descent step of unit length in the largest gradient component.
fn two_loop(memory: &VecDeque<(Vec<f64>, Vec<f64>, f64)>, gradient: &[f64]) -> Vec<f64> {
    let mut q = gradient.to_vec();
    let mut alphas = Vec::with_capacity(memory.len());
    for (s, y, rho) in memory.iter().rev() {
        let alpha = rho * dot(s, &q);
        for (qi, yi) in q.iter_mut().zip(y) {
            *qi -= alpha * yi;
        }
        alphas.push(alpha);
    }
    let scale = match memory.back() {
        Some((s, y, _)) => dot(s, y) / dot(y, y),
        None => 1.0 / gradient.iter().fold(1.0f64, |m, g| m.max(g.abs())),
    };
    for qi in &mut q {
        *qi *= scale;
    }
    for ((s, y, rho), alpha) in memory.iter().zip(alphas.iter().rev()) {
        let beta = rho * dot(y, &q);
        for (qi, si) in q.iter_mut().zip(s) {
            *qi += (alpha - beta) * si;
        }
    }
    for qi in &mut q {
        *qi = -*qi;
    }
    q
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// Maximises `f` over the unit box from `x0` by compass search: try ± `step` along each
/// axis, move to the best improvement, halve the step when nothing improves; stop below
/// `min_step` or after `max_evaluations`. Returns the point and its value.
pub fn compass_search(
    mut f: impl FnMut(&[f64]) -> f64,
    x0: Vec<f64>,
    value0: f64,
    mut step: f64,
    min_step: f64,
    max_evaluations: usize,
) -> (Vec<f64>, f64) {
    let mut x = x0;
    let mut value = value0;
    let mut evaluations = 0;
    let mut trial = x.clone();
    while step >= min_step && evaluations < max_evaluations {
        let mut best: Option<(usize, f64, f64)> = None;
        for axis in 0..x.len() {
            for sign in [-1.0, 1.0] {
                let moved = (x[axis] + sign * step).clamp(0.0, 1.0);
                if moved == x[axis] {
                    continue;
                }
                trial.copy_from_slice(&x);
                trial[axis] = moved;
                let trial_value = f(&trial);
                evaluations += 1;
                if trial_value > best.map_or(value, |(_, _, v)| v) {
                    best = Some((axis, moved, trial_value));
                }
            }
        }
        match best {
            Some((axis, moved, trial_value)) => {
                x[axis] = moved;
                value = trial_value;
            }
            None => step *= 0.5,
        }
    }
    (x, value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lbfgs_finds_the_rosenbrock_minimum() {
        let rosenbrock = |x: &[f64], g: &mut [f64]| {
            let (a, b) = (x[0], x[1]);
            g[0] = -2.0 * (1.0 - a) - 400.0 * a * (b - a * a);
            g[1] = 200.0 * (b - a * a);
            (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2)
        };
        let minimum = lbfgs(rosenbrock, vec![-1.2, 1.0], 200);
        assert!(minimum.value < 1e-8, "{minimum:?}");
        assert!((minimum.x[0] - 1.0).abs() < 1e-4 && (minimum.x[1] - 1.0).abs() < 1e-4);
    }

    #[test]
    fn lbfgs_backs_away_from_non_finite_values() {
        // log barrier: undefined for x <= 0, minimum at x = 1.
        let barrier = |x: &[f64], g: &mut [f64]| {
            g[0] = 1.0 - 1.0 / x[0];
            if x[0] > 0.0 {
                x[0] - x[0].ln()
            } else {
                f64::NAN
            }
        };
        let minimum = lbfgs(barrier, vec![8.0], 100);
        assert!((minimum.x[0] - 1.0).abs() < 1e-5, "{minimum:?}");
    }

    #[test]
    fn compass_search_climbs_to_a_box_maximum_and_stays_inside() {
        let peak = |x: &[f64]| -(x[0] - 0.3).powi(2) - (x[1] - 1.4).powi(2);
        let start = vec![0.9, 0.2];
        let (x, value) = compass_search(peak, start.clone(), peak(&start), 0.25, 1e-4, 10_000);
        assert!((x[0] - 0.3).abs() < 1e-3, "{x:?}");
        assert_eq!(x[1], 1.0, "the maximum on the box lies on its edge");
        assert!((value - peak(&x)).abs() < 1e-15);
    }
}
