//! The agent's model of a two-axis mount, `image = offset + gain · command + Σ band[a] · dir[a]`
//! (`band`: the shift a dead band puts on the feature after a move one way; `dir` 0 where none is
//! modelled), as a linear-Gaussian belief over the ten numbers, with chi-square tests on it.

use nalgebra::{Matrix2, SMatrix, SVector, Vector2};

use super::model::{Affine, Vec2, distance};
use super::tuning::{
    CHI2_MEDIAN, CORE_EXHAUSTIVE, CORE_SHARE, GATE_CONFIDENCE, PRIOR_BAND_PX,
    PRIOR_GAIN_PX_PER_STEP, PRIOR_OFFSET_PX, WIDENING_ROUNDS, WIDENING_SETTLED,
};
use crate::imaging::median;

/// The chi-square quantile of two degrees of freedom at probability `p` (exponential, mean 2).
pub fn chi2_quantile(p: f64) -> f64 {
    -2.0 * (1.0 - p).ln()
}

/// The squared Mahalanobis radius a 2-D error falls within at probability `p`, its scale estimated
/// with `freedom` degrees of freedom (0: known): twice the F(2, ν) quantile, chi-square as ν grows.
pub fn quantile(p: f64, freedom: usize) -> f64 {
    if freedom == 0 {
        return chi2_quantile(p);
    }
    let v = freedom as f64;
    v * ((1.0 - p).powf(-2.0 / v) - 1.0)
}

/// Whether a zero-mean error of covariance `cov` (px²) lies within `tolerance` px at `confidence`.
fn sure_within(cov: Matrix2<f64>, tolerance: f64, confidence: f64, freedom: usize) -> bool {
    let largest = cov.symmetric_eigenvalues().max();
    largest * quantile(confidence, freedom) <= tolerance * tolerance
}

/// The covariance of a 2-D position that scatters by `px` per axis, independently, px².
pub fn isotropic(px: f64) -> Matrix2<f64> {
    Matrix2::identity() * px * px
}

const PARAMETERS: usize = 10;

/// Two px-per-axis columns (rows: image x and y; columns: the two axes).
pub type PerAxis = [[f64; 2]; 2];

/// No direction on either axis: a command whose dead band the model does not fit.
pub const STILL: Vec2 = [0.0; 2];

type Vector = SVector<f64, PARAMETERS>;
type Matrix = SMatrix<f64, PARAMETERS, PARAMETERS>;

/// One sighting; `dir`: each axis's last move direction (+1, -1; 0 if unknown or unmodelled).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Point {
    pub command: Vec2,
    pub dir: Vec2,
    pub image: Vec2,
}

/// The observation matrix of command `u` (relative to the origin) reached moving in `dir`.
fn observation(u: Vec2, dir: Vec2) -> SMatrix<f64, 2, PARAMETERS> {
    SMatrix::<f64, 2, PARAMETERS>::from_row_slice(&[
        1.0, 0.0, u[0], u[1], 0.0, 0.0, dir[0], 0.0, dir[1], 0.0, //
        0.0, 1.0, 0.0, 0.0, u[0], u[1], 0.0, dir[0], 0.0, dir[1],
    ])
}

/// The belief about one mount's response, in information form; commands relative to `origin`.
#[derive(Clone, Debug)]
pub struct Response {
    origin: Vec2,
    information: Matrix,
    projected: Vector,
}

impl Response {
    /// Nothing known but broad bounds ([`PRIOR_OFFSET_PX`], [`PRIOR_GAIN_PX_PER_STEP`]).
    pub fn broad(origin: Vec2) -> Self {
        let nothing = Affine::linear([[0.0; 2]; 2]);
        Self::with_prior(origin, nothing, PRIOR_GAIN_PX_PER_STEP)
    }

    /// A prior centred on `mean` (no dead band), the gain's standard deviation `gain_sd` px/step.
    pub fn with_prior(origin: Vec2, mean: Affine, gain_sd: f64) -> Self {
        let at = mean.predict(origin);
        let [[a, b], [c, d]] = mean.gain;
        let x = Vector::from_column_slice(&[at[0], at[1], a, b, c, d, 0.0, 0.0, 0.0, 0.0]);
        let [o, g, l] = [PRIOR_OFFSET_PX, gain_sd, PRIOR_BAND_PX].map(|sd| sd.powi(-2));
        let information =
            Matrix::from_diagonal(&Vector::from_column_slice(&[o, o, g, g, g, g, l, l, l, l]));
        Self {
            origin,
            projected: information * x,
            information,
        }
    }

    fn relative(&self, command: Vec2) -> Vec2 {
        [command[0] - self.origin[0], command[1] - self.origin[1]]
    }

    /// Learns from a sighting `point`, measured with covariance `noise` (px²).
    pub fn add(&mut self, point: Point, noise: Matrix2<f64>) {
        let h = observation(self.relative(point.command), point.dir);
        let Some(weight) = noise.try_inverse() else {
            return;
        };
        let ht_w = h.transpose() * weight;
        self.information += ht_w * h;
        self.projected += ht_w * Vector2::new(point.image[0], point.image[1]);
    }

    /// The mean of the ten numbers; `None` only if the information is not positive definite.
    fn estimate(&self) -> Option<Vector> {
        Some(self.information.cholesky()?.solve(&self.projected))
    }

    /// The most likely map for commands reached with the axes last moving in `dir`.
    pub fn mean(&self, dir: Vec2) -> Option<Affine> {
        self.means().map(|mean| mean(dir))
    }

    /// [`Self::mean`] for any direction, the numbers solved for once.
    fn means(&self) -> Option<impl Fn(Vec2) -> Affine + '_> {
        let x = self.estimate()?;
        let [[a, b], [c, d]] = [[x[2], x[3]], [x[4], x[5]]];
        let [o0, o1] = self.origin;
        Some(move |dir: Vec2| {
            let band = [0, 1].map(|row| dir[0] * x[6 + row] + dir[1] * x[8 + row]);
            Affine {
                offset: [
                    x[0] - a * o0 - b * o1 + band[0],
                    x[1] - c * o0 - d * o1 + band[1],
                ],
                gain: [[a, b], [c, d]],
            }
        })
    }

    /// The most likely gain (px per step) and each axis's band shift after a positive move, px.
    pub fn gain_and_band(&self) -> Option<(PerAxis, PerAxis)> {
        let x = self.estimate()?;
        Some(([[x[2], x[3]], [x[4], x[5]]], [[x[6], x[8]], [x[7], x[9]]]))
    }

    /// Where `command`, reached moving in `dir`, puts the feature, and its model covariance (px²).
    fn predict(&self, command: Vec2, dir: Vec2) -> Option<(Vec2, Matrix2<f64>)> {
        let cholesky = self.information.cholesky()?;
        let (x, p) = (cholesky.solve(&self.projected), cholesky.inverse());
        let h = observation(self.relative(command), dir);
        let mean = h * x;
        Some(([mean[0], mean[1]], h * p * h.transpose()))
    }

    /// The squared Mahalanobis distance of `point` from the prediction, its own `noise` added.
    fn surprise(&self, point: Point, noise: Matrix2<f64>) -> Option<f64> {
        let (mean, cov) = self.predict(point.command, point.dir)?;
        let miss = Vector2::new(point.image[0] - mean[0], point.image[1] - mean[1]);
        let inverse = (cov + noise).try_inverse()?;
        Some((miss.transpose() * inverse * miss)[0])
    }

    /// Whether a sighting's innovation passes the chi-square test at [`GATE_CONFIDENCE`].
    pub fn believes(&self, point: Point, noise: Matrix2<f64>) -> bool {
        self.surprise(point, noise)
            .is_none_or(|d2| d2 <= chi2_quantile(GATE_CONFIDENCE))
    }
}

/// The model of `points` each with an isotropic scatter of `noise` px.
pub fn model_of(points: &[Point], noise: f64) -> Response {
    let n = points.len().max(1) as f64;
    let origin = [0, 1].map(|a| points.iter().map(|p| p.command[a]).sum::<f64>() / n);
    let r = isotropic(noise);
    let mut model = Response::broad(origin);
    for point in points {
        model.add(*point, r);
    }
    model
}

/// The sum of squared misses of `subset` from `model`, px².
pub fn squares(model: &Response, subset: &[Point]) -> f64 {
    let means = model.means();
    subset
        .iter()
        .map(|p| {
            means.as_ref().map_or(f64::INFINITY, |mean| {
                let at = mean(p.dir).predict(p.command);
                (at[0] - p.image[0]).powi(2) + (at[1] - p.image[1]).powi(2)
            })
        })
        .sum()
}

/// The model of the [`CORE_SHARE`] of `points` it fits best (at least `min_keep`); `None` if all.
fn core(points: &[Point], noise: f64, min_keep: usize) -> Option<Response> {
    let keep = ((CORE_SHARE * points.len() as f64).ceil() as usize).max(min_keep);
    if keep >= points.len() {
        return None;
    }
    if points.len() <= CORE_EXHAUSTIVE {
        return (0u32..1 << points.len())
            .filter(|mask| mask.count_ones() as usize == keep)
            .map(|mask| {
                let subset: Vec<Point> = (0..points.len())
                    .filter(|i| mask & (1 << i) != 0)
                    .map(|i| points[i])
                    .collect();
                let model = model_of(&subset, noise);
                (squares(&model, &subset), model)
            })
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, model)| model);
    }
    let mut subset = points.to_vec();
    let mut model = model_of(&subset, noise);
    while subset.len() > keep {
        let worst = {
            let mean = model.means()?;
            let off = |p: &Point| distance(mean(p.dir).predict(p.command), p.image);
            let misses = subset.iter().map(off);
            misses.enumerate().max_by(|a, b| a.1.total_cmp(&b.1))?.0
        };
        subset.remove(worst);
        model = model_of(&subset, noise);
    }
    Some(model)
}

/// The model of `points` (scatter `noise` px) less those failing a chi-square test against the
/// [`CORE_SHARE`] they fit best (keeping `min_keep`); scatter beyond `noise` widens the test.
pub fn robust_fit(points: &[Point], noise: f64, min_keep: usize) -> Option<Fit> {
    let fit = |response, kept, widening| Fit {
        response,
        kept,
        widening,
        noise,
    };
    let full = model_of(points, noise);
    let Some(core) = core(points, noise, min_keep) else {
        let widening = residual_widening(&full, points, noise);
        return Some(fit(full, points.to_vec(), widening));
    };
    let r = isotropic(noise);
    let surprises: Vec<f64> = points
        .iter()
        .map(|p| core.surprise(*p, r).unwrap_or(0.0))
        .collect();
    // The core fits its own sightings closer than a new one: the median innovation only starts
    // the scatter's estimate, which the kept sightings' residuals refine until it stops growing.
    let mut widening = (median(surprises.clone())? / CHI2_MEDIAN).max(1.0);
    let kept_at = |widening: f64| -> Vec<Point> {
        let gate = chi2_quantile(GATE_CONFIDENCE) * widening;
        let kept = points.iter().zip(&surprises).filter(|(_, d2)| **d2 <= gate);
        kept.map(|(p, _)| *p).collect()
    };
    for _ in 0..WIDENING_ROUNDS {
        let kept = kept_at(widening);
        if kept.len() < min_keep {
            let widening = widening.max(residual_widening(&full, points, noise));
            return Some(fit(full, points.to_vec(), widening));
        }
        let response = model_of(&kept, noise);
        let refreshed = residual_widening(&response, &kept, noise);
        if refreshed <= widening * WIDENING_SETTLED {
            return Some(fit(response, kept, widening.max(refreshed)));
        }
        widening = refreshed;
    }
    let kept = kept_at(widening);
    Some(fit(model_of(&kept, noise), kept, widening))
}

/// How many times `noise`² the `points` scatter by about `model` (residual variance, at least 1).
fn residual_widening(model: &Response, points: &[Point], noise: f64) -> f64 {
    let freedom = residual_freedom(points);
    if freedom == 0 {
        return 1.0;
    }
    (squares(model, points) / (freedom as f64 * noise * noise)).max(1.0)
}

/// The degrees of freedom `points` leave: two each, less six and two per banded axis.
pub fn residual_freedom(points: &[Point]) -> usize {
    let bands = (0..2)
        .filter(|&a| points.iter().any(|p| p.dir[a] != 0.0))
        .count();
    (2 * points.len()).saturating_sub(6 + 2 * bands)
}

/// A model fitted to sightings by [`robust_fit`].
#[derive(Clone, Debug)]
pub struct Fit {
    pub response: Response,
    pub kept: Vec<Point>,
    /// How many times the detector's variance the sightings scatter by (at least 1).
    widening: f64,
    /// The scatter of one sighting it was fitted with, px (the detector's).
    noise: f64,
}

impl Fit {
    /// Whether a new sighting passes the chi-square test, widened as the kept sightings showed.
    pub fn believes(&self, point: Point) -> bool {
        let r = isotropic(self.noise) * self.widening;
        self.response.believes(point, r)
    }

    /// The covariance (px²) of where `command`, reached moving in `dir`, lands the feature: the
    /// model's widened uncertainty plus the bench's own scatter, which no fit averages away.
    fn error_at(&self, command: Vec2, dir: Vec2) -> Option<Matrix2<f64>> {
        let (_, cov) = self.response.predict(command, dir)?;
        let bench = (self.widening - 1.0) * self.noise * self.noise;
        Some(cov * self.widening + Matrix2::identity() * bench)
    }

    /// Whether the feature lands within `tolerance` px of the prediction at `confidence`.
    pub fn sure_at(&self, command: Vec2, dir: Vec2, tolerance: f64, confidence: f64) -> bool {
        let freedom = if self.widening > 1.0 {
            residual_freedom(&self.kept)
        } else {
            0
        };
        self.error_at(command, dir)
            .is_some_and(|cov| sure_within(cov, tolerance, confidence, freedom))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth() -> Affine {
        Affine {
            offset: [320.0, 240.0],
            gain: [[0.05, -0.01], [0.02, 0.04]],
        }
    }

    fn noise(px: f64) -> Matrix2<f64> {
        Matrix2::identity() * px * px
    }

    /// A sighting at `image` for `command`, no band modelled.
    fn at(command: Vec2, image: Vec2) -> Point {
        Point {
            command,
            dir: STILL,
            image,
        }
    }

    /// Deterministic scatter in [-1, 1].
    fn wobble(i: usize) -> f64 {
        ((i as f64 * 12.9898).sin() * 43_758.547).fract()
    }

    #[test]
    fn learns_an_exact_map_and_grows_sure_with_sightings() {
        let mut model = Response::broad([0.0, 0.0]);
        let commands = [[0.0, 0.0], [400.0, 0.0], [0.0, 400.0], [400.0, 400.0]];
        let mut spreads = Vec::new();
        for u in commands {
            model.add(at(u, truth().predict(u)), noise(1.0));
            let (_, cov) = model.predict([200.0, 200.0], STILL).unwrap();
            spreads.push(cov.trace());
        }
        let fitted = model.mean(STILL).unwrap();
        for (row, want) in fitted.gain.iter().zip(truth().gain) {
            for (g, w) in row.iter().zip(want) {
                assert!((g - w).abs() < 1e-6, "{fitted:?}");
            }
        }
        assert!((fitted.offset[0] - 320.0).abs() < 1e-3, "{fitted:?}");
        assert!(spreads.windows(2).all(|w| w[1] < w[0]), "{spreads:?}");
        let (_, cov) = model.predict([200.0, 200.0], STILL).unwrap();
        assert!(sure_within(cov, 3.0, 0.95, 0), "{cov}");
        assert!(!sure_within(cov, 0.1, 0.95, 0), "{cov}");
    }

    #[test]
    fn a_sighting_far_off_the_model_fails_the_chi_square_test() {
        let mut model = Response::broad([0.0, 0.0]);
        for (i, u) in [
            [0.0, 0.0],
            [300.0, 0.0],
            [0.0, 300.0],
            [300.0, 300.0],
            [150.0, 0.0],
        ]
        .into_iter()
        .enumerate()
        {
            let p = truth().predict(u);
            model.add(at(u, [p[0] + wobble(i), p[1] - wobble(i + 7)]), noise(1.0));
        }
        let u = [100.0, 200.0];
        let p = truth().predict(u);
        assert!(model.believes(at(u, [p[0] + 1.5, p[1] - 1.0]), noise(1.0)));
        assert!(!model.believes(at(u, [p[0] + 25.0, p[1]]), noise(1.0)));
        // The same miss is believed of a sighting the detector itself gives 15 px of scatter.
        assert!(model.believes(at(u, [p[0] + 25.0, p[1]]), noise(15.0)));
    }

    #[test]
    fn a_foreign_sighting_is_set_aside_and_bench_scatter_is_not() {
        // Sixteen sightings on a grid; a scatter of about 2 px per axis on 0.5 px of
        // detector noise: the bench's (a screw's pitch error), every sighting has it.
        let scatter =
            |i: usize| (wobble(i) + wobble(i + 100) + wobble(i + 200)) * 2.0 / 3f64.sqrt();
        let mut points: Vec<Point> = (0..16)
            .map(|i| {
                let u = [(i % 4) as f64 * 200.0, (i / 4) as f64 * 200.0];
                let p = truth().predict(u);
                at(u, [p[0] + scatter(i), p[1] + scatter(i + 50)])
            })
            .collect();
        let fit = robust_fit(&points, 0.5, 4).unwrap();
        assert_eq!(fit.kept, points);
        assert!(fit.widening > 1.0, "{}", fit.widening);
        // Another beam 60 px off taken for this one.
        points[5].image[0] += 60.0;
        let fit = robust_fit(&points, 0.5, 4).unwrap();
        assert_eq!(fit.kept.len(), 15, "{:?}", fit.kept);
        assert!(!fit.kept.contains(&points[5]));
        let fitted = fit.response.mean(STILL).unwrap();
        assert!((fitted.gain[0][0] - 0.05).abs() < 0.005, "{fitted:?}");
    }

    #[test]
    fn a_scale_from_few_residuals_asks_for_a_wider_radius() {
        // Fisher's F(2, 2) and F(2, 10) at 0.95 are 19.0 and 4.103 (tables); d² is twice F.
        assert!((quantile(0.95, 2) - 38.0).abs() < 1e-9);
        assert!((quantile(0.95, 10) - 8.206).abs() < 1e-2);
        // Known outright, or pinned by many residuals: the chi-square quantile.
        assert_eq!(quantile(0.95, 0), chi2_quantile(0.95));
        assert!((quantile(0.95, 100_000) - chi2_quantile(0.95)).abs() < 1e-3);
    }

    #[test]
    fn the_error_at_a_new_command_carries_the_scatter_the_sightings_showed() {
        let grid = |scatter: f64| -> Vec<Point> {
            (0..9)
                .map(|i| {
                    let u = [(i % 3) as f64 * 300.0, (i / 3) as f64 * 300.0];
                    let p = truth().predict(u);
                    at(
                        u,
                        [p[0] + scatter * wobble(i), p[1] + scatter * wobble(i + 30)],
                    )
                })
                .collect()
        };
        let sd = |fit: &Fit| {
            let cov = fit.error_at([300.0, 300.0], STILL).unwrap();
            cov.symmetric_eigenvalues().max().sqrt()
        };
        // Sightings as exact as the detector says: the error is what the fit does not know,
        // well below the detector's own scatter.
        let exact = robust_fit(&grid(0.0), 0.5, 4).unwrap();
        assert_eq!(exact.widening, 1.0);
        assert!(sd(&exact) < 0.5, "{}", sd(&exact));
        // Sightings scattered by several pixels (a screw's pitch error): a new command meets
        // that scatter too, whatever the detector says of one centre.
        let scattered = robust_fit(&grid(5.0), 0.5, 4).unwrap();
        assert!(scattered.widening > 10.0, "{}", scattered.widening);
        assert!(sd(&scattered) > 1.5, "{}", sd(&scattered));
        // With no more sightings than numbers to fit, nothing shows a scatter.
        let three: Vec<Point> = grid(5.0).into_iter().take(3).collect();
        assert_eq!(robust_fit(&three, 0.5, 4).unwrap().widening, 1.0);
    }

    #[test]
    fn a_nominal_prior_needs_fewer_sightings() {
        let nominal = Affine {
            offset: [0.0; 2],
            gain: truth().gain,
        };
        let mut model = Response::with_prior([0.0, 0.0], nominal, 0.002);
        model.add(at([0.0, 0.0], truth().predict([0.0, 0.0])), noise(1.0));
        let (mean, cov) = model.predict([500.0, -300.0], STILL).unwrap();
        let want = truth().predict([500.0, -300.0]);
        assert!(
            (mean[0] - want[0]).hypot(mean[1] - want[1]) < 0.5,
            "{mean:?}"
        );
        assert!(cov.trace().sqrt() < 3.0, "{cov}");
        // With nothing known of the response, one sighting says nothing of another command.
        let mut broad = Response::broad([0.0, 0.0]);
        broad.add(at([0.0, 0.0], truth().predict([0.0, 0.0])), noise(1.0));
        let (_, cov) = broad.predict([500.0, -300.0], STILL).unwrap();
        assert!(cov.trace().sqrt() > 1000.0, "{cov}");
    }
}
