//! The agent's model of one two-axis actuator ([`Tracker`]): where its feature was seen for which
//! command, the bench model fitted to that, and the choice of the next probe.

use std::ops::RangeInclusive;

use super::bench::{self, Point};
use super::tuning::{
    ACROSS_REACH_PROBES, ACROSS_SHORTENING, BAND_CONFIDENCE, BAND_MIN_SIGHTINGS, BAND_PER_SIDE,
    BAND_WORTH_NOISES, MIN_SPREAD_PROBES, PROBE_MULTIPLES, PROBE_SHARES, ROBUST_MIN_POINTS,
    ROUGH_BALANCE, ROUGH_REACH, SAME_COMMAND_SHARE, SAME_STEP, SEARCH_REFINEMENTS, SEARCH_RINGS,
};

/// A 2-vector (motor steps or pixels).
pub type Vec2 = [f64; 2];

/// `image = offset + gain · command`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Affine {
    pub offset: Vec2,
    /// Rows are image x and y, columns the two motor axes, px per step.
    pub gain: [[f64; 2]; 2],
}

impl Affine {
    pub fn linear(gain: [[f64; 2]; 2]) -> Self {
        Self {
            offset: [0.0; 2],
            gain,
        }
    }

    pub fn predict(&self, command: Vec2) -> Vec2 {
        [0, 1].map(|r| self.offset[r] + self.gain[r][0] * command[0] + self.gain[r][1] * command[1])
    }

    /// The command that puts the feature at `point`, when the gain is invertible.
    pub fn solve(&self, point: Vec2) -> Option<Vec2> {
        let [[a, b], [c, d]] = self.gain;
        let det = a * d - b * c;
        if det.abs() < 1e-12 {
            return None;
        }
        let [rx, ry] = [point[0] - self.offset[0], point[1] - self.offset[1]];
        Some([(d * rx - b * ry) / det, (a * ry - c * rx) / det])
    }

    /// The same gain, offset to pass exactly through `image` at `command`.
    pub fn anchored(&self, command: Vec2, image: Vec2) -> Affine {
        let moved = self.predict(command);
        Affine {
            offset: [0, 1].map(|a| self.offset[a] + image[a] - moved[a]),
            gain: self.gain,
        }
    }

    /// The gain's smaller singular value over its larger (0: one direction does not move it).
    fn balance(&self) -> f64 {
        let [[a, b], [c, d]] = self.gain;
        let frobenius = a * a + b * b + c * c + d * d;
        let det = (a * d - b * c).abs();
        let root = (frobenius * frobenius - 4.0 * det * det).max(0.0).sqrt();
        let large = ((frobenius + root) / 2.0).sqrt();
        let small = ((frobenius - root) / 2.0).max(0.0).sqrt();
        if large > 0.0 { small / large } else { 0.0 }
    }
}

/// Whether the commands spread by at least `min_spread` steps (RMS) along their weakest direction.
fn spans_both_axes(points: &[Point], min_spread: f64) -> bool {
    if points.len() < 3 {
        return false;
    }
    let n = points.len() as f64;
    let mean = |f: &dyn Fn(&Point) -> f64| points.iter().map(f).sum::<f64>() / n;
    let (mu, mv) = (mean(&|p| p.command[0]), mean(&|p| p.command[1]));
    let suu = mean(&|p| (p.command[0] - mu).powi(2));
    let svv = mean(&|p| (p.command[1] - mv).powi(2));
    let suv = mean(&|p| (p.command[0] - mu) * (p.command[1] - mv));
    let det = suu * svv - suv * suv;
    let trace = suu + svv;
    let weakest = trace / 2.0 - ((trace / 2.0).powi(2) - det).max(0.0).sqrt();
    weakest >= min_spread * min_spread
}

/// The bench model's map of `points` for direction `dir`, none set aside, once they span both axes.
fn fit(points: &[Point], dir: Vec2, noise: f64, min_spread: f64) -> Option<Affine> {
    if !spans_both_axes(points, min_spread) {
        return None;
    }
    bench::model_of(points, noise).mean(dir)
}

/// The larger of a response's two columns' lengths: px per step of the stronger axis.
pub fn column_norm(gain: [[f64; 2]; 2]) -> f64 {
    gain[0][0]
        .hypot(gain[1][0])
        .max(gain[0][1].hypot(gain[1][1]))
}

/// Where a feature seen at `at` under command `from` shows under `to`, by the response `gain`.
pub fn carried(gain: [[f64; 2]; 2], from: Vec2, at: Vec2, to: Vec2) -> Vec2 {
    Affine { offset: at, gain }.predict([to[0] - from[0], to[1] - from[1]])
}

pub fn distance(a: Vec2, b: Vec2) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// The first of `points` nearest `place`.
pub fn nearest_point(points: impl IntoIterator<Item = Vec2>, place: Vec2) -> Option<Vec2> {
    points
        .into_iter()
        .min_by(|a, b| distance(*a, place).total_cmp(&distance(*b, place)))
}

/// A square grid of `spacing` around `centre`, ring by ring outwards (ring k: its 8k points).
pub fn square_rings(centre: Vec2, spacing: Vec2, multiples: RangeInclusive<i32>) -> Vec<Vec2> {
    multiples
        .flat_map(|k| {
            (-k..=k)
                .flat_map(move |i| (-k..=k).map(move |j| (i, j)))
                .filter(move |(i, j)| i.abs().max(j.abs()) == k)
        })
        .map(|(i, j)| [0, 1].map(|a| centre[a] + f64::from([i, j][a]) * spacing[a]))
        .collect()
}

/// Eight commands around `centre` (axes first, then diagonals) at each multiple of `spacing`.
pub fn rings(centre: Vec2, spacing: Vec2, multiples: RangeInclusive<i32>) -> Vec<Vec2> {
    multiples
        .flat_map(|k| {
            let (sx, sy) = (spacing[0] * f64::from(k), spacing[1] * f64::from(k));
            [
                [sx, 0.0],
                [-sx, 0.0],
                [0.0, sy],
                [0.0, -sy],
                [sx, sy],
                [-sx, sy],
                [sx, -sy],
                [-sx, -sy],
            ]
        })
        .map(|d| [centre[0] + d[0], centre[1] + d[1]])
        .collect()
}

/// How far a feature at `from` can move either way along unit `direction` inside image `view`.
fn room(from: Vec2, direction: Vec2, view: Vec2) -> f64 {
    (0..2)
        .filter(|&axis| direction[axis].abs() > 1e-9)
        .map(|axis| from[axis].min(view[axis] - from[axis]) / direction[axis].abs())
        .fold(f64::INFINITY, f64::min)
        .max(0.0)
}

/// How a detected beam serves the model.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Sighting {
    /// Its centre can be fitted to.
    Clean(Vec2),
    /// The centre of a spot the border cuts, extrapolated by a spot fit.
    Fitted(Vec2),
    /// Roughly where it is (cut, merged, speckled).
    Partial(Vec2),
}

impl Sighting {
    pub fn fit_centre(self) -> Option<Vec2> {
        match self {
            Sighting::Clean(c) | Sighting::Fitted(c) => Some(c),
            Sighting::Partial(_) => None,
        }
    }
}

/// One sighting; `dir`: the direction each axis last moved in (+1, -1; 0 before its first move).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sight {
    pub command: Vec2,
    pub image: Vec2,
    pub dir: Vec2,
    /// When it was made, counting every sighting of the tracker.
    pub order: usize,
    /// Extrapolated from a spot the border cut ([`Sighting::Fitted`]).
    pub fitted: bool,
}

impl Sight {
    /// This sighting for the bench model, its direction kept only on the axes `band` marks.
    fn point(&self, band: [bool; 2]) -> Point {
        Point {
            command: self.command,
            dir: on_axes(self.dir, band),
            image: self.image,
        }
    }
}

fn on_axes(dir: Vec2, mask: [bool; 2]) -> Vec2 {
    [0, 1].map(|a| if mask[a] { dir[a] } else { 0.0 })
}

/// What the agent knows about one feature driven by one two-axis actuator.
#[derive(Clone, Debug, Default)]
pub struct Tracker {
    /// Sightings a map may be fitted to ([`Sighting::Clean`] or [`Sighting::Fitted`]).
    pub clean: Vec<Sight>,
    /// Sightings where it showed only partly (clipped, overlapped): where it roughly was.
    pub partial: Vec<Sight>,
    pub missing: Vec<Vec2>,
    /// Probe length per axis, steps.
    pub probe: Vec2,
    /// Permitted command range per axis, `[min, max]`.
    pub range: [Vec2; 2],
    /// Minimum spread of clean commands for a fit, steps.
    pub min_spread: f64,
    /// The direction each axis last moved in.
    dir: Vec2,
    previous_dir: Vec2,
    /// The command the mount was last sent to.
    current: Option<Vec2>,
    /// The axes whose sightings showed an uncompensated dead band; only these get one in the fit.
    band: [bool; 2],
    /// The scatter of one measured position, px.
    pub noise: f64,
    made: usize,
    /// Spacing per axis of a square search grid whose views tile the command space, steps.
    pub search_grid: Option<Vec2>,
    /// The last command where the feature did not show, while nothing was seen since.
    lost_at: Option<Vec2>,
}

impl Tracker {
    pub fn new(probe: Vec2, range: [Vec2; 2]) -> Self {
        Self {
            probe,
            range,
            min_spread: MIN_SPREAD_PROBES * probe[0].min(probe[1]),
            noise: 1.0,
            ..Self::default()
        }
    }

    /// Books a commanded move from `from` to `to`: the axes that moved set their direction.
    pub fn moved(&mut self, from: Vec2, to: Vec2) {
        self.previous_dir = self.dir;
        self.dir = self.heading(from, to);
        self.current = Some(to);
    }

    /// The axes' directions after a move from `from` to `command` (one that stays keeps its last).
    fn heading(&self, from: Vec2, command: Vec2) -> Vec2 {
        [0, 1].map(|a| {
            let step = command[a] - from[a];
            if step.abs() >= SAME_STEP {
                step.signum()
            } else {
                self.dir[a]
            }
        })
    }

    /// [`Self::heading`] from the command the mount was last sent to, on the banded axes.
    fn dir_towards(&self, command: Vec2) -> Vec2 {
        let from = self.current.unwrap_or(command);
        on_axes(self.heading(from, command), self.band)
    }

    /// Motion lost when an axis reverses, steps: the fitted band's width on banded axes, else 0.
    pub fn lost(&self) -> Vec2 {
        let fitted = (self.band != [false; 2])
            .then(|| self.response())
            .flatten()
            .and_then(|fit| fit.response.gain_and_band());
        let Some((gain, shift)) = fitted else {
            return [0.0; 2];
        };
        let unit = Affine::linear(gain);
        // The shift after a move the positive way is the gain times minus half the band.
        [0, 1].map(|a| {
            let half = unit
                .solve([shift[0][a], shift[1][a]])
                .map_or(0.0, |steps| (-steps[a]).max(0.0));
            if self.band[a] { 2.0 * half } else { 0.0 }
        })
    }

    /// The clean sightings to fit: whole ones if they span both axes; on `band` axes, after a move.
    fn points(&self, band: [bool; 2]) -> Vec<Point> {
        let known: Vec<&Sight> = self
            .clean
            .iter()
            .filter(|s| (0..2).all(|a| !band[a] || s.dir[a] != 0.0))
            .collect();
        let whole: Vec<Point> = known
            .iter()
            .filter(|s| !s.fitted)
            .map(|s| s.point(band))
            .collect();
        if whole.len() < known.len() && spans_both_axes(&whole, self.min_spread) {
            return whole;
        }
        known.iter().map(|s| s.point(band)).collect()
    }

    /// The fitted map for the way the axes last moved, once the clean sightings span both axes.
    pub fn model(&self) -> Option<Affine> {
        self.response()?.response.mean(on_axes(self.dir, self.band))
    }

    /// The bench model of the clean sightings, less those its chi-square test sets aside.
    fn response(&self) -> Option<bench::Fit> {
        let points = self.points(self.band);
        if !spans_both_axes(&points, self.min_spread) {
            return None;
        }
        bench::robust_fit(&points, self.noise, ROBUST_MIN_POINTS)
    }

    /// Whether `command` lands the feature within `tolerance` px of the prediction at `confidence`.
    fn sure_at(&self, command: Vec2, tolerance: f64, confidence: f64) -> bool {
        self.response().is_some_and(|fit| {
            fit.sure_at(command, self.dir_towards(command), tolerance, confidence)
        })
    }

    /// Whether `command` surely puts the feature on `target`, and the model `before` the latest
    /// sightings agrees: a refit that moved the final command has not settled.
    pub fn settled_at(
        &self,
        before: &Tracker,
        command: Vec2,
        target: Vec2,
        tolerance: f64,
        confidence: f64,
    ) -> bool {
        self.sure_at(command, tolerance, confidence) && before.believes(command, target)
    }

    /// Whether a sighting at `image` for `command` passes the chi-square test (`true` without one).
    pub fn believes(&self, command: Vec2, image: Vec2) -> bool {
        self.response().is_none_or(|fit| {
            fit.believes(Point {
                command,
                dir: self.dir_towards(command),
                image,
            })
        })
    }

    /// `fit`'s map for `dir`, anchored at the latest clean sighting the fit kept.
    fn local_model(&self, fit: &bench::Fit, dir: Vec2) -> Option<Affine> {
        let model = fit.response.mean(dir)?;
        let Some(anchor) = self
            .clean
            .iter()
            .rev()
            .map(|s| s.point(self.band))
            .find(|point| fit.kept.contains(point))
        else {
            return Some(model);
        };
        let own = fit.response.mean(anchor.dir)?;
        let anchored = own.anchored(anchor.command, anchor.image);
        Some(Affine {
            offset: [0, 1].map(|r| anchored.offset[r] + (model.offset[r] - own.offset[r])),
            gain: model.gain,
        })
    }

    /// Where the feature shows once the mount is sent from where it is now to `command`.
    pub fn predict(&self, command: Vec2) -> Option<Vec2> {
        let model = self.local_model(&self.response()?, self.dir_towards(command))?;
        Some(model.predict(command))
    }

    /// The command, within range, that puts the feature at `point` when sent from `from`; a banded
    /// axis uses the map of the direction the move takes.
    pub fn command_for(&self, point: Vec2, from: Vec2) -> Option<Vec2> {
        let fit = self.response()?;
        let solve = |dir: Vec2| self.local_model(&fit, dir)?.solve(point);
        let mut dir = on_axes(self.dir, self.band);
        let mut target = solve(dir)?;
        for _ in 0..2 {
            let next = on_axes(self.heading(from, target), self.band);
            if next == dir {
                break;
            }
            dir = next;
            target = solve(dir)?;
        }
        let command = [0, 1].map(|a| {
            if (target[a] - from[a]).abs() < SAME_STEP {
                from[a]
            } else {
                target[a]
            }
        });
        Some(self.clamp(command))
    }

    /// Looks for a dead band on each axis with enough clean sightings after moves either way, taken
    /// if significant ([`BAND_CONFIDENCE`]) and over [`BAND_WORTH_NOISES`]; true if one was taken.
    pub fn estimate_band(&mut self) -> bool {
        let eligible = [0, 1].map(|a| {
            let [plus, minus] =
                [1.0, -1.0].map(|sign| self.clean.iter().filter(|s| s.dir[a] * sign > 0.0).count());
            plus + minus >= BAND_MIN_SIGHTINGS && plus.min(minus) >= BAND_PER_SIDE
        });
        let with = self.points([0, 1].map(|a| self.band[a] || eligible[a]));
        let freedom = bench::residual_freedom(&with);
        if freedom == 0 || !spans_both_axes(&with, self.min_spread) {
            return false;
        }
        let squares =
            |points: &[Point]| bench::squares(&bench::model_of(points, self.noise), points);
        let after = squares(&with);
        let scatter = (after / freedom as f64).max(self.noise * self.noise);
        let mut found = false;
        let unbanded = [0, 1].map(|a| eligible[a] && !self.band[a]);
        for axis in (0..2).filter(|&a| unbanded[a]) {
            let mut without = with.clone();
            without.iter_mut().for_each(|p| p.dir[axis] = 0.0);
            let explained = (squares(&without) - after).max(0.0);
            let significant = explained / scatter > bench::quantile(BAND_CONFIDENCE, freedom);
            let worth = (explained / with.len() as f64).sqrt() > BAND_WORTH_NOISES * self.noise;
            if significant && worth {
                self.band[axis] = true;
                found = true;
            }
        }
        found
    }

    pub fn claims(&self, command: Vec2) -> serde_json::Value {
        serde_json::json!({
            "sightings": {
                "clean": self.clean.len(),
                "partial": self.partial.len(),
                "missing": self.missing.len(),
            },
            "response_px_per_step": self.model().map(|m| m.gain),
            "lost_motion_steps": self.lost(),
            "predicted_px": self.predict(command),
        })
    }

    /// Records a clean sighting, replacing one at the same command and direction.
    pub fn add_clean(&mut self, command: Vec2, image: Vec2) {
        self.file_with(command, Sighting::Clean(image), self.dir);
    }

    /// Forgets the clean sightings at `command`, so a repeated frame there does not count twice.
    pub fn forget_clean(&mut self, command: Vec2) {
        self.clean
            .retain(|s| distance(s.command, command) >= SAME_STEP);
    }

    /// Files what was seen at the current `command` (or that nothing was).
    pub fn file(&mut self, command: Vec2, seen: Option<Sighting>) {
        match seen {
            Some(seen) => self.file_with(command, seen, self.dir),
            None => self.add_missing(command),
        }
    }

    fn file_with(&mut self, command: Vec2, seen: Sighting, dir: Vec2) {
        self.made += 1;
        self.lost_at = None;
        let (Sighting::Clean(image) | Sighting::Fitted(image) | Sighting::Partial(image)) = seen;
        let sight = Sight {
            command,
            image,
            dir,
            order: self.made,
            fitted: matches!(seen, Sighting::Fitted(_)),
        };
        if let Sighting::Partial(_) = seen {
            self.partial.push(sight);
        } else {
            self.clean
                .retain(|s| distance(s.command, command) >= SAME_STEP || s.dir != dir);
            self.clean.push(sight);
        }
    }

    /// Files what was seen at `command` before the last move, as the mount was then.
    pub fn file_before_move(&mut self, command: Vec2, seen: Sighting) {
        self.file_with(command, seen, self.previous_dir);
    }

    pub fn add_missing(&mut self, command: Vec2) {
        self.lost_at = Some(command);
        self.missing.push(command);
    }

    /// Whether nothing was tried at `command` (within a share of the shorter probe).
    fn untried(&self, command: Vec2) -> bool {
        let same = (SAME_COMMAND_SHARE * self.probe[0].min(self.probe[1])).max(SAME_STEP);
        !self.tried_within(command, same)
    }

    /// Whether anything was seen or missed within `within` steps of `command`.
    pub fn tried_within(&self, command: Vec2, within: f64) -> bool {
        let near = |u: &Vec2| distance(*u, command) < within;
        let seen = self.sightings().map(|s| &s.command);
        seen.chain(&self.missing).any(near)
    }

    pub fn spans(&self) -> Vec2 {
        self.range.map(|r| r[1] - r[0])
    }

    pub fn shorter_span(&self) -> f64 {
        let [a, b] = self.spans();
        a.min(b)
    }

    /// The shortest and longest probe, steps: [`PROBE_SHARES`] of the shorter span.
    pub fn probe_bounds(&self) -> Vec2 {
        PROBE_SHARES.map(|share| share * self.shorter_span())
    }

    /// The probe scaled by `factor`, within [`Self::probe_bounds`].
    pub fn scaled_probe(&self, factor: f64) -> Vec2 {
        let [lo, hi] = self.probe_bounds();
        self.probe.map(|p| (p * factor).clamp(lo, hi))
    }

    pub fn clamp(&self, command: Vec2) -> Vec2 {
        [0, 1].map(|a| command[a].clamp(self.range[a][0], self.range[a][1]))
    }

    /// The next probe: along an axis not yet spanned, near a partial sighting, or a search.
    pub fn next_probe(&self, start: Vec2) -> Vec2 {
        let [px, py] = self.probe;
        let candidates: Vec<Vec2> = if let Some(last) = self.clean.last() {
            let base = last.command;
            let spans = |axis: usize| {
                self.clean
                    .iter()
                    .any(|s| (s.command[axis] - base[axis]).abs() >= self.min_spread)
            };
            let mut dirs: Vec<Vec2> = [0, 1]
                .into_iter()
                .filter(|&axis| !spans(axis) || self.clean.len() >= 2)
                .flat_map(|axis| {
                    let d = [0, 1].map(|a| if a == axis { self.probe[a] } else { 0.0 });
                    [d, [-d[0], -d[1]]]
                })
                .collect();
            // Axes not yet spanned first.
            dirs.sort_by_key(|d| spans(usize::from(d[1] != 0.0)));
            PROBE_MULTIPLES
                .into_iter()
                .flat_map(|m| dirs.iter().map(move |d| [0, 1].map(|a| base[a] + m * d[a])))
                .collect()
        } else if let Some(last) = self.partial.last() {
            rings(last.command, self.probe, 1..=1)
        } else if let Some(grid) = self.search_grid {
            // A grid point within half a spacing of a miss on both axes sees what it saw.
            let covered = |c: &Vec2| {
                self.missing
                    .iter()
                    .any(|m| (0..2).all(|a| (c[a] - m[a]).abs() < grid[a] / 2.0))
            };
            square_rings(start, grid, 1..=SEARCH_RINGS)
                .into_iter()
                .map(|c| self.clamp(c))
                .filter(|c| !covered(c))
                .collect()
        } else {
            rings(start, [2.0 * px, 2.0 * py], 1..=6)
        };
        // Then finer grids: a beam that moves more per step than assumed hides between points.
        let finer = (0..=SEARCH_REFINEMENTS).flat_map(|level| {
            let spacing = self.probe.map(|p| p / f64::from(1 << level));
            square_rings(start, spacing, 1..=SEARCH_RINGS)
        });
        candidates
            .into_iter()
            .chain(finer)
            .map(|c| self.clamp(c))
            .find(|c| self.untried(*c))
            .unwrap_or_else(|| self.clamp([start[0] + px, start[1] + py]))
    }

    pub fn is_fresh(&self) -> bool {
        self.clean.is_empty() && self.partial.is_empty() && self.missing.is_empty()
    }

    /// The next probe while steering the feature towards `target`, `margin` px inside image `view`.
    pub fn next_probe_towards(&self, start: Vec2, view: Vec2, target: Vec2, margin: f64) -> Vec2 {
        if self.is_fresh() {
            return self.clamp([start[0] + self.probe[0], start[1]]);
        }
        self.rough_aim(target)
            .or_else(|| self.probe_across(view, target, margin))
            .or_else(|| self.back_the_other_way())
            .unwrap_or_else(|| self.next_probe(start))
    }

    /// Without a fitted map, the rough map's command half-way to `target`, at most [`ROUGH_REACH`]
    /// probes per axis: a cut beam's centroid moves less, so the rough map overestimates.
    fn rough_aim(&self, target: Vec2) -> Option<Vec2> {
        if self.model().is_some() {
            return None;
        }
        let (rough, latest) = self.rough_map()?;
        let base = latest.command;
        let halfway = [0, 1].map(|a| (latest.image[a] + target[a]) / 2.0);
        let aim = rough.solve(halfway)?;
        let command = self.clamp([0, 1].map(|a| {
            let reach = ROUGH_REACH * self.probe[a];
            aim[a].clamp(base[a] - reach, base[a] + reach)
        }));
        self.untried(command).then_some(command)
    }

    /// The steering sightings' map, through the latest of them, and that one, unless degenerate.
    fn rough_map(&self) -> Option<(Affine, Sight)> {
        let sights = self.steering_sightings();
        let points: Vec<Point> = sights.iter().map(|s| s.point(self.band)).collect();
        let latest = *sights.last()?;
        let dir = on_axes(latest.dir, self.band);
        let rough = fit(&points, dir, self.noise, self.min_spread)?;
        if rough.balance() < ROUGH_BALANCE {
            return None;
        }
        Some((rough.anchored(latest.command, latest.image), latest))
    }

    /// The best map there is: the fitted one, else the rough one.
    pub fn steering_map(&self) -> Option<Affine> {
        self.response()
            .and_then(|fit| self.local_model(&fit, on_axes(self.dir, self.band)))
            .or_else(|| self.rough_map().map(|(rough, _)| rough))
    }

    pub fn latest(&self) -> Option<&Sight> {
        self.sightings().max_by_key(|s| s.order)
    }

    /// Every sighting, the clean ones first.
    fn sightings(&self) -> impl Iterator<Item = &Sight> {
        self.clean.iter().chain(&self.partial)
    }

    /// After a move lost the feature, the same move the other way from where it last showed.
    fn back_the_other_way(&self) -> Option<Vec2> {
        let lost = self.lost_at?;
        let last = self.latest()?;
        let back = self.clamp([0, 1].map(|a| 2.0 * last.command[a] - lost[a]));
        self.untried(back).then_some(back)
    }

    /// The sightings to steer by: the clean ones once two span a direction, else all of them.
    fn steering_sightings(&self) -> Vec<Sight> {
        let spans = self.clean.last().is_some_and(|last| {
            self.clean
                .iter()
                .any(|s| distance(s.command, last.command) >= self.min_spread)
        });
        if spans {
            return self.clean.clone();
        }
        let mut all: Vec<Sight> = self.sightings().copied().collect();
        all.sort_by_key(|s| s.order);
        all
    }

    fn probe_across(&self, view: Vec2, target: Vec2, margin: f64) -> Option<Vec2> {
        let sights = self.steering_sightings();
        let last = sights.last()?;
        let (base, seen) = (last.command, last.image);
        let far = sights
            .iter()
            .max_by(|a, b| distance(a.command, base).total_cmp(&distance(b.command, base)))?;
        let span = distance(far.command, base);
        if span < self.min_spread {
            return None;
        }
        let along = [0, 1].map(|a| (far.command[a] - base[a]) / span);
        let response = [0, 1].map(|a| (far.image[a] - seen[a]) / span);
        let strength = response[0].powi(2) + response[1].powi(2);
        if strength < 1e-12 {
            return None;
        }
        let probe = self.probe[0] * along[1].abs() + self.probe[1] * along[0].abs();
        let reach = ACROSS_REACH_PROBES * probe.max(span);
        let travel = (((target[0] - seen[0]) * response[0] + (target[1] - seen[1]) * response[1])
            / strength)
            .clamp(-reach, reach);
        // Across, pointing the positive way of the axis it mostly moves.
        let across = if along[0].abs() > along[1].abs() {
            [-along[1] * along[0].signum(), along[0].abs()]
        } else {
            [along[1].abs(), -along[0] * along[1].signum()]
        };
        // The across response is not known yet: take the same size, at right angles.
        let landing = [0, 1].map(|a| seen[a] + travel * response[a]);
        let size = strength.sqrt();
        let sideways = [-response[1] / size, response[0] / size];
        let room = room(landing, sideways, view) - margin;
        let full = (room / (size * probe)).clamp(1.0 / ACROSS_SHORTENING, 1.0);
        let short = full / ACROSS_SHORTENING;
        [full, -full, short, -short]
            .into_iter()
            .map(|share| {
                let step = share * probe;
                self.clamp([0, 1].map(|a| base[a] + travel * along[a] + step * across[a]))
            })
            .find(|c| {
                let spread = (c[0] - base[0]) * across[0] + (c[1] - base[1]) * across[1];
                spread.abs() >= self.min_spread && self.untried(*c)
            })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::policy::vision::tuning::DONE_CONFIDENCE;

    #[test]
    fn fits_an_exact_affine_map() {
        // Exact but for the broad prior's pull, about a micropixel.
        let truth = Affine {
            offset: [900.0, 500.0],
            gain: [[0.17, 0.012], [-0.01, -0.16]],
        };
        let still = bench::STILL;
        let points: Vec<Point> = [[0.0, 0.0], [2000.0, 0.0], [0.0, 2000.0], [1500.0, -700.0]]
            .iter()
            .map(|&command| Point {
                command,
                dir: still,
                image: truth.predict(command),
            })
            .collect();
        let fit = fit(&points, still, 1.0, 100.0).unwrap();
        assert!(
            points
                .iter()
                .all(|p| distance(fit.predict(p.command), p.image) < 1e-3)
        );
        let u = fit.solve([960.0, 540.0]).unwrap();
        assert!(distance(truth.predict(u), [960.0, 540.0]) < 1e-3);
        assert!(super::fit(&points[..2], still, 1.0, 100.0).is_none());
    }

    #[test]
    fn probes_an_unspanned_axis_next() {
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        tracker.add_clean([0.0, 0.0], [100.0, 100.0]);
        tracker.add_clean([1500.0, 0.0], [350.0, 100.0]);
        assert_eq!(tracker.next_probe([0.0, 0.0]), [1500.0, 1500.0]);
    }

    #[test]
    fn a_grid_search_skips_the_points_a_miss_already_looked_at() {
        let mut tracker = Tracker::new([500.0, 500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        tracker.search_grid = Some([2000.0, 1000.0]);
        let first = tracker.next_probe([0.0, 0.0]);
        assert!(distance(first, [0.0, 0.0]) > 999.0, "{first:?}");
        // The other mirror's search looked at that patch through a nearby command.
        tracker.add_missing([first[0] + 700.0, first[1] - 350.0]);
        let next = tracker.next_probe([0.0, 0.0]);
        assert!(
            (next[0] - first[0]).abs() >= 1000.0 || (next[1] - first[1]).abs() >= 500.0,
            "{first:?} then {next:?}"
        );
    }

    #[test]
    fn probes_across_while_centring_along_a_known_direction() {
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        assert_eq!(
            tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], [960.0, 540.0], 40.0),
            [1500.0, 0.0]
        );
        // 0.2 px per step along the first axis: 500 px short of the target is 2500 steps.
        tracker.add_clean([0.0, 0.0], [160.0, 540.0]);
        tracker.add_clean([1500.0, 0.0], [460.0, 540.0]);
        let next = tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], [960.0, 540.0], 40.0);
        assert!(distance(next, [4000.0, 1500.0]) < 1e-6, "{next:?}");
        tracker.add_missing(next);
        let next = tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], [960.0, 540.0], 40.0);
        assert!(distance(next, [4000.0, -1500.0]) < 1e-6, "{next:?}");
    }

    /// Where the load of a mount with a dead band of `band` steps per axis sits once the
    /// motor goes to `command` from a load at `load`: an axis commanded within half the
    /// band of its load leaves it; beyond, the load trails the command by half the band.
    fn settle(load: Vec2, command: Vec2, band: Vec2) -> Vec2 {
        [0, 1].map(|axis| {
            let half = band[axis] / 2.0;
            load[axis].clamp(command[axis] - half, command[axis] + half)
        })
    }

    #[test]
    fn a_dead_band_is_found_from_reversals_and_compensated() {
        let truth = Affine {
            offset: [900.0, 500.0],
            gain: [[0.17, 0.012], [-0.01, -0.16]],
        };
        // The mount has 300 steps of play on each axis: on a reversal the motor turns
        // 300 steps before the load follows.
        let band = [300.0, 300.0];
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        // The motor's command and the load, as the bench has them.
        let mut mount = ([0.0, 0.0], [0.0, 0.0]);
        let go = |tracker: &mut Tracker, mount: &mut (Vec2, Vec2), next: Vec2| {
            tracker.moved(mount.0, next);
            *mount = (next, settle(mount.1, next, band));
            tracker.add_clean(next, truth.predict(mount.1));
        };
        for next in [
            [1500.0, 0.0],
            [1500.0, 1500.0],
            [0.0, 1500.0],
            [0.0, 0.0],
            [2500.0, -1000.0],
            [-1000.0, 800.0],
            [600.0, 300.0],
            [1800.0, -700.0],
            [-300.0, 1200.0],
        ] {
            go(&mut tracker, &mut mount, next);
        }
        assert_eq!(tracker.lost(), [0.0, 0.0]);
        assert!(tracker.estimate_band());
        assert!(
            (tracker.lost()[0] - 300.0).abs() < 1.0 && (tracker.lost()[1] - 300.0).abs() < 1.0,
            "{:?}",
            tracker.lost()
        );
        // A target reached by reversing both axes lands where it is meant to, as predicted.
        let seen_now = truth.predict(mount.1);
        let target = [seen_now[0] + 60.0, seen_now[1] + 40.0];
        let command = tracker.command_for(target, mount.0).unwrap();
        assert!(distance(tracker.predict(command).unwrap(), target) < 0.5);
        go(&mut tracker, &mut mount, command);
        assert!(distance(truth.predict(mount.1), target) < 0.5);
        // Without reversals there is nothing to measure.
        let mut forward = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        let mut mount = ([0.0, 0.0], [0.0, 0.0]);
        for i in 1..=10 {
            go(
                &mut forward,
                &mut mount,
                [400.0 * i as f64, 250.0 * i as f64],
            );
        }
        assert!(!forward.estimate_band());
        assert_eq!(forward.lost(), [0.0, 0.0]);
    }

    #[test]
    fn a_sighting_of_another_beam_does_not_anchor_the_predictions() {
        let truth = Affine {
            offset: [900.0, 500.0],
            gain: [[0.17, 0.012], [-0.01, -0.16]],
        };
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        let mut at = [0.0, 0.0];
        for next in [
            [1500.0, 0.0],
            [1500.0, 1500.0],
            [0.0, 1500.0],
            [-1500.0, 0.0],
            [0.0, -1500.0],
            [800.0, 700.0],
        ] {
            tracker.moved(at, next);
            at = next;
            tracker.add_clean(next, truth.predict(next));
        }
        // The latest sighting is another beam, 150 px from where this one was.
        let next = [400.0, -300.0];
        tracker.moved(at, next);
        let elsewhere = [truth.predict(next)[0] + 150.0, truth.predict(next)[1]];
        tracker.add_clean(next, elsewhere);
        let target = [1200.0, 300.0];
        let predicted = tracker.predict(target).unwrap();
        assert!(
            distance(predicted, truth.predict(target)) < 1.0,
            "{predicted:?}"
        );
    }

    #[test]
    fn the_tracker_sets_aside_a_foreign_sighting_and_knows_when_it_is_sure() {
        let truth = Affine {
            offset: [900.0, 500.0],
            gain: [[0.17, 0.012], [-0.01, -0.16]],
        };
        // A tracker of three probes' exact sightings of `map`, and where the mount ends.
        let probed = |map: &Affine| {
            let mut tracker =
                Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
            let mut at = [0.0, 0.0];
            for next in [[1500.0, 0.0], [1500.0, 1500.0], [0.0, 1500.0]] {
                tracker.moved(at, next);
                at = next;
                tracker.add_clean(next, map.predict(next));
            }
            (tracker, at)
        };
        let (mut tracker, at) = probed(&truth);
        let u = [700.0, 600.0];
        let seen = truth.predict(u);
        assert!(tracker.believes(u, [seen[0] + 2.0, seen[1]]));
        assert!(!tracker.believes(u, [seen[0] + 40.0, seen[1]]));
        // Four exact sightings a probe apart pin the map to well within 3 px near them,
        // not to within a tenth of a pixel.
        tracker.moved(at, u);
        tracker.add_clean(u, seen);
        assert!(tracker.sure_at(u, 3.0, DONE_CONFIDENCE));
        assert!(!tracker.sure_at(u, 0.1, DONE_CONFIDENCE));
        // Settled only where the model before the last sighting agrees: one that had the
        // response a fifth stronger puts the command elsewhere.
        assert!(tracker.settled_at(&tracker.clone(), u, seen, 3.0, DONE_CONFIDENCE));
        let stronger = Affine {
            gain: truth.gain.map(|row| row.map(|g| 1.2 * g)),
            ..truth
        };
        let (earlier, _) = probed(&stronger);
        assert!(!tracker.settled_at(&earlier, u, seen, 3.0, DONE_CONFIDENCE));
    }
}
