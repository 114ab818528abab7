//! Where a mirror's lost axes are, from one sighting of its beam: the response model
//! `beam = anchor + M · (steps - reference)` solved for the lost axes by weighted least
//! squares (the known axis, if any, held at its position), and the offsets between the
//! axes' counters and their true positions combined over several sightings, with their
//! covariance from the detector's covariance of each centre and the calibration's
//! residual.

use nalgebra::{DMatrix, DVector, Matrix2};

/// A linear response of a beam to two axes: `anchor_px + matrix · (steps - reference)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Response {
    pub anchor_px: [f64; 2],
    pub reference_steps: [f64; 2],
    pub matrix: [[f64; 2]; 2],
    /// The model's own error per image coordinate (the calibration's residual RMS), px.
    pub residual_px: f64,
}

/// A measured beam position with the detector's covariance, px and px².
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sighting {
    pub centre_px: [f64; 2],
    pub covariance: [[f64; 2]; 2],
}

/// What one sighting says about the lost axes: `true position - counter` for each lost
/// axis (in the order of `lost`), and its covariance split into the detector's part and
/// the model's.
#[derive(Clone, Debug, PartialEq)]
pub struct Offset {
    pub steps: Vec<f64>,
    pub detector: DMatrix<f64>,
    pub model: DMatrix<f64>,
}

/// The offset of the lost axes seen in `sighting` when the axes' counters read `counters`
/// (task steps; those of known axes are their true positions). `None` when the lost axes
/// do not move the beam (a singular response).
pub fn locate(
    response: &Response,
    sighting: &Sighting,
    counters: [f64; 2],
    lost: &[usize],
) -> Option<Offset> {
    if lost.is_empty() || lost.iter().any(|&k| k > 1) {
        return None;
    }
    let m = Matrix2::new(
        response.matrix[0][0],
        response.matrix[0][1],
        response.matrix[1][0],
        response.matrix[1][1],
    );
    let known: Vec<usize> = (0..2).filter(|k| !lost.contains(k)).collect();
    // What the beam shows beyond the anchor and the known axes' part.
    let mut seen = nalgebra::Vector2::new(
        sighting.centre_px[0] - response.anchor_px[0],
        sighting.centre_px[1] - response.anchor_px[1],
    );
    for &k in &known {
        seen -= m.column(k) * (counters[k] - response.reference_steps[k]);
    }
    let design = DMatrix::from_fn(2, lost.len(), |row, col| m[(row, lost[col])]);
    let detector = to_matrix(sighting.covariance);
    let model = Matrix2::identity() * response.residual_px.powi(2);
    let weight = (detector + model).try_inverse()?;
    let weight = DMatrix::from_fn(2, 2, |r, c| weight[(r, c)]);
    let normal = design.transpose() * &weight * &design;
    let normal_inverse = normal.try_inverse()?;
    if normal_inverse.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // steps - reference = gain · seen, for the lost axes.
    let gain = &normal_inverse * design.transpose() * &weight;
    let seen = DVector::from_column_slice(seen.as_slice());
    let solved = &gain * seen;
    let steps = lost
        .iter()
        .enumerate()
        .map(|(i, &k)| solved[i] + response.reference_steps[k] - counters[k])
        .collect();
    let propagate = |covariance: Matrix2<f64>| {
        let covariance = DMatrix::from_fn(2, 2, |r, c| covariance[(r, c)]);
        &gain * covariance * gain.transpose()
    };
    Some(Offset {
        steps,
        detector: propagate(detector),
        model: propagate(model),
    })
}

fn to_matrix(m: [[f64; 2]; 2]) -> Matrix2<f64> {
    Matrix2::new(m[0][0], m[0][1], m[1][0], m[1][1])
}

/// Offsets from several sightings combined: their mean, with the detector's parts
/// averaged as independent and the model's kept whole (the calibration errs alike at
/// nearby positions), and how far apart the sightings are.
#[derive(Clone, Debug, PartialEq)]
pub struct Combined {
    pub steps: Vec<f64>,
    /// One standard deviation per lost axis, steps.
    pub sigma: Vec<f64>,
    /// The largest Mahalanobis distance between two sightings' offsets (0 for one): the
    /// detector and model parts of both counted as independent.
    pub spread: f64,
}

/// Combines the offsets of one mirror's sightings (at least one, all of the same axes).
pub fn combine(offsets: &[Offset]) -> Option<Combined> {
    let first = offsets.first()?;
    let n = first.steps.len();
    let count = offsets.len() as f64;
    let mut steps = vec![0.0; n];
    let mut detector = DMatrix::zeros(n, n);
    let mut model = DMatrix::zeros(n, n);
    for offset in offsets {
        for (sum, value) in steps.iter_mut().zip(&offset.steps) {
            *sum += value / count;
        }
        detector += &offset.detector / (count * count);
        model += &offset.model / count;
    }
    let covariance = detector + model;
    let sigma = (0..n).map(|i| covariance[(i, i)].max(0.0).sqrt()).collect();
    let mut spread: f64 = 0.0;
    for (i, a) in offsets.iter().enumerate() {
        for b in &offsets[i + 1..] {
            let difference =
                DVector::from_iterator(n, a.steps.iter().zip(&b.steps).map(|(x, y)| x - y));
            let joint = &a.detector + &a.model + &b.detector + &b.model;
            let distance = joint
                .try_inverse()
                .map(|inverse| (difference.transpose() * inverse * &difference)[(0, 0)].sqrt())
                .unwrap_or(f64::INFINITY);
            spread = spread.max(distance);
        }
    }
    Some(Combined {
        steps,
        sigma,
        spread,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn response() -> Response {
        Response {
            anchor_px: [240.0, 135.0],
            reference_steps: [100.0, -200.0],
            matrix: [[0.0425, 0.003], [-0.0025, -0.04]],
            residual_px: 0.1,
        }
    }

    fn seen_at(response: &Response, steps: [f64; 2]) -> Sighting {
        let d = [
            steps[0] - response.reference_steps[0],
            steps[1] - response.reference_steps[1],
        ];
        let m = response.matrix;
        Sighting {
            centre_px: [
                response.anchor_px[0] + m[0][0] * d[0] + m[0][1] * d[1],
                response.anchor_px[1] + m[1][0] * d[0] + m[1][1] * d[1],
            ],
            covariance: [[0.01, 0.0], [0.0, 0.01]],
        }
    }

    #[test]
    fn both_lost_axes_are_found_through_the_inverse_response() {
        let r = response();
        let truth = [1234.0, -987.0];
        let counters = [50.0, 40.0];
        let offset = locate(&r, &seen_at(&r, truth), counters, &[0, 1]).unwrap();
        assert!((offset.steps[0] - (truth[0] - counters[0])).abs() < 1e-6);
        assert!((offset.steps[1] - (truth[1] - counters[1])).abs() < 1e-6);
        // σ ≈ sqrt(0.01 + 0.01) px / 0.0425 px/step ≈ 3.3 steps on the first axis.
        let sigma = (offset.detector[(0, 0)] + offset.model[(0, 0)]).sqrt();
        assert!((3.0..3.7).contains(&sigma), "{sigma}");
    }

    #[test]
    fn a_known_axis_is_held_and_only_the_lost_one_solved() {
        let r = response();
        let truth = [700.0, 300.0];
        // Axis 1 is known (its counter is its position); axis 0's counter is off by 500.
        let offset = locate(&r, &seen_at(&r, truth), [200.0, 300.0], &[0]).unwrap();
        assert_eq!(offset.steps.len(), 1);
        assert!((offset.steps[0] - 500.0).abs() < 1e-6, "{offset:?}");
        let sigma = (offset.detector[(0, 0)] + offset.model[(0, 0)]).sqrt();
        assert!((3.0..3.7).contains(&sigma), "{sigma}");
    }

    #[test]
    fn an_axis_that_moves_nothing_cannot_be_located() {
        let r = Response {
            matrix: [[0.04, 0.0], [0.0, 0.0]],
            ..response()
        };
        assert!(locate(&r, &seen_at(&r, [0.0, 0.0]), [0.0, 0.0], &[1]).is_none());
        assert!(locate(&r, &seen_at(&r, [0.0, 0.0]), [0.0, 0.0], &[]).is_none());
    }

    #[test]
    fn sightings_average_and_their_disagreement_is_measured() {
        let r = response();
        let a = locate(&r, &seen_at(&r, [1000.0, 0.0]), [0.0, 0.0], &[0, 1]).unwrap();
        let b = locate(&r, &seen_at(&r, [1300.0, 0.0]), [300.0, 0.0], &[0, 1]).unwrap();
        let combined = combine(&[a.clone(), b]).unwrap();
        assert!((combined.steps[0] - 1000.0).abs() < 1e-6);
        assert!(combined.spread < 1e-6);
        // The model's part is not averaged away: σ stays above the model's alone.
        let model_only = a.model[(0, 0)].sqrt();
        assert!(combined.sigma[0] > model_only, "{combined:?}");
        // A sighting 40 steps off is many standard deviations away.
        let c = locate(&r, &seen_at(&r, [1340.0, 0.0]), [300.0, 0.0], &[0, 1]).unwrap();
        let apart = combine(&[a, c]).unwrap();
        assert!(apart.spread > 5.0, "{apart:?}");
    }
}
