//! The agent's model of one two-axis actuator: observations of where a feature was seen for
//! which motor command, an affine motor-to-image map fitted to them by least squares, and
//! the choice of the next probe (an axis not yet moved, or an expanding search when the
//! feature has not been seen).

use std::ops::RangeInclusive;

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
    /// Where the feature shows for `command`.
    pub fn predict(&self, command: Vec2) -> Vec2 {
        let [[a, b], [c, d]] = self.gain;
        [
            self.offset[0] + a * command[0] + b * command[1],
            self.offset[1] + c * command[0] + d * command[1],
        ]
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

    /// The same response passing exactly through one observation: local corrections from
    /// the latest sighting do not inherit the fit's offset error.
    pub fn anchored(&self, command: Vec2, image: Vec2) -> Affine {
        let moved = self.predict(command);
        Affine {
            offset: [
                self.offset[0] + image[0] - moved[0],
                self.offset[1] + image[1] - moved[1],
            ],
            gain: self.gain,
        }
    }

    /// Least-squares fit to `(command, image)` pairs; `None` unless the commands span both
    /// axes by at least `min_spread` steps (RMS about their mean along the weaker direction).
    pub fn fit(points: &[(Vec2, Vec2)], min_spread: f64) -> Option<Affine> {
        if points.len() < 3 {
            return None;
        }
        let n = points.len() as f64;
        let mean = |f: &dyn Fn(&(Vec2, Vec2)) -> f64| points.iter().map(f).sum::<f64>() / n;
        let (mu, mv) = (mean(&|p| p.0[0]), mean(&|p| p.0[1]));
        let (mx, my) = (mean(&|p| p.1[0]), mean(&|p| p.1[1]));
        let suu = mean(&|p| (p.0[0] - mu).powi(2));
        let svv = mean(&|p| (p.0[1] - mv).powi(2));
        let suv = mean(&|p| (p.0[0] - mu) * (p.0[1] - mv));
        let det = suu * svv - suv * suv;
        let trace = suu + svv;
        let weakest = trace / 2.0 - ((trace / 2.0).powi(2) - det).max(0.0).sqrt();
        if weakest < min_spread * min_spread {
            return None;
        }
        let mut gain = [[0.0; 2]; 2];
        for (axis, m) in [mx, my].into_iter().enumerate() {
            let su = mean(&|p| (p.0[0] - mu) * (p.1[axis] - m));
            let sv = mean(&|p| (p.0[1] - mv) * (p.1[axis] - m));
            gain[axis] = [(su * svv - sv * suv) / det, (sv * suu - su * suv) / det];
        }
        let offset = [
            mx - gain[0][0] * mu - gain[0][1] * mv,
            my - gain[1][0] * mu - gain[1][1] * mv,
        ];
        Some(Affine { offset, gain })
    }
}

/// Euclidean distance.
pub fn distance(a: Vec2, b: Vec2) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

/// Eight commands around `centre` (the axes first, then the diagonals) at each multiple
/// `k` of `spacing`.
fn rings(centre: Vec2, spacing: Vec2, multiples: RangeInclusive<i32>) -> Vec<Vec2> {
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

/// A probe across a known direction keeps the feature's centre this far inside the
/// image, px.
const IN_VIEW_MARGIN_PX: f64 = 40.0;

/// How far a feature at `from` can move either way along the unit `direction` and stay
/// inside an image of size `view`.
fn room(from: Vec2, direction: Vec2, view: Vec2) -> f64 {
    let exit = |sign: f64| {
        (0..2)
            .map(|axis| {
                let step = sign * direction[axis];
                if step > 1e-9 {
                    (view[axis] - from[axis]) / step
                } else if step < -1e-9 {
                    from[axis] / -step
                } else {
                    f64::INFINITY
                }
            })
            .fold(f64::INFINITY, f64::min)
    };
    exit(1.0).min(exit(-1.0)).max(0.0)
}

/// Commands closer than this count as the same probe, steps.
const SAME_COMMAND: f64 = 100.0;

/// Commands closer than this are the very same command, steps.
pub const SAME_STEP: f64 = 1.0;

/// What the agent knows about one feature driven by one two-axis actuator.
#[derive(Clone, Debug)]
pub struct Tracker {
    /// Commands where the feature was measured cleanly (whole, not clipped or overlapped).
    pub clean: Vec<(Vec2, Vec2)>,
    /// Commands where the feature showed only partly (clipped, overlapped): where it roughly was.
    pub partial: Vec<(Vec2, Vec2)>,
    /// Commands where the feature did not show.
    pub missing: Vec<Vec2>,
    /// Probe length per axis, steps.
    pub probe: Vec2,
    /// Permitted command range per axis, `[min, max]`.
    pub range: [Vec2; 2],
    /// Minimum spread of clean commands for a fit, steps.
    pub min_spread: f64,
}

impl Tracker {
    pub fn new(probe: Vec2, range: [Vec2; 2]) -> Self {
        Self {
            clean: Vec::new(),
            partial: Vec::new(),
            missing: Vec::new(),
            probe,
            range,
            min_spread: probe[0].min(probe[1]) / 4.0,
        }
    }

    /// The fitted model, once the clean observations span both axes.
    pub fn model(&self) -> Option<Affine> {
        Affine::fit(&self.clean, self.min_spread)
    }

    /// The fitted model anchored at the latest clean sighting.
    pub fn local_model(&self) -> Option<Affine> {
        let model = self.model()?;
        Some(match self.clean.last() {
            Some(&(command, image)) => model.anchored(command, image),
            None => model,
        })
    }

    /// What the tracker believes, for the transcript: how many sightings of each kind, the
    /// fitted response and where it puts the feature for `command`.
    pub fn claims(&self, command: Vec2) -> serde_json::Value {
        let model = self.local_model();
        serde_json::json!({
            "sightings": {
                "clean": self.clean.len(),
                "partial": self.partial.len(),
                "missing": self.missing.len(),
            },
            "response_px_per_step": model.map(|m| m.gain),
            "predicted_px": model.map(|m| m.predict(command)),
        })
    }

    /// Records a clean observation, replacing an earlier one at the same command.
    pub fn add_clean(&mut self, command: Vec2, image: Vec2) {
        self.clean
            .retain(|(u, _)| distance(*u, command) >= SAME_STEP);
        self.clean.push((command, image));
    }

    pub fn add_partial(&mut self, command: Vec2, image: Vec2) {
        self.partial.push((command, image));
    }

    pub fn add_missing(&mut self, command: Vec2) {
        self.missing.push(command);
    }

    /// Whether any observation (clean, partial or missing) was made within `within` steps
    /// of `command`.
    pub fn tried_within(&self, command: Vec2, within: f64) -> bool {
        let near = |u: &Vec2| distance(*u, command) < within;
        self.clean.iter().any(|(u, _)| near(u))
            || self.partial.iter().any(|(u, _)| near(u))
            || self.missing.iter().any(near)
    }

    /// Clamps a command into the permitted range.
    pub fn clamp(&self, command: Vec2) -> Vec2 {
        [
            command[0].clamp(self.range[0][0], self.range[0][1]),
            command[1].clamp(self.range[1][0], self.range[1][1]),
        ]
    }

    /// The next command to learn the response: a move along an axis the clean observations
    /// do not yet span, or, while the feature has not been measured cleanly, a step away
    /// from where it showed partly, or an expanding search around the start.
    pub fn next_probe(&self, start: Vec2) -> Vec2 {
        self.next_probe_preferring(start, None)
    }

    /// [`Self::next_probe`], trying moves of axis `prefer` first around a partial sighting
    /// (a feature cut by the top or bottom border needs the axis that moves it vertically).
    fn next_probe_preferring(&self, start: Vec2, prefer: Option<usize>) -> Vec2 {
        let [px, py] = self.probe;
        let candidates: Vec<Vec2> = if let Some(&(base, _)) = self.clean.last() {
            let spans = |axis: usize| {
                self.clean
                    .iter()
                    .any(|(u, _)| (u[axis] - base[axis]).abs() >= self.min_spread)
            };
            let mut dirs = Vec::new();
            for axis in [0, 1] {
                if !spans(axis) || self.clean.len() >= 2 {
                    let mut d = [0.0; 2];
                    d[axis] = self.probe[axis];
                    dirs.push(d);
                    dirs.push([-d[0], -d[1]]);
                }
            }
            // Axes not yet spanned first.
            dirs.sort_by_key(|d| usize::from(spans(usize::from(d[1] != 0.0))));
            let mut out: Vec<Vec2> = dirs
                .iter()
                .map(|d| [base[0] + d[0], base[1] + d[1]])
                .collect();
            out.extend(
                dirs.iter()
                    .map(|d| [base[0] + 2.0 * d[0], base[1] + 2.0 * d[1]]),
            );
            out
        } else if let Some(&(base, _)) = self.partial.last() {
            let mut around = rings(base, self.probe, 1..=1);
            if let Some(axis) = prefer {
                around.sort_by_key(|c| usize::from(c[1 - axis] != base[1 - axis]));
            }
            around
        } else {
            rings(start, [2.0 * px, 2.0 * py], 1..=6)
        };
        // When all of those were tried, a finer search around the start.
        candidates
            .into_iter()
            .chain(rings(start, self.probe, 1..=12))
            .map(|c| self.clamp(c))
            .find(|c| !self.tried_within(*c, SAME_COMMAND))
            .unwrap_or_else(|| self.clamp([start[0] + px, start[1] + py]))
    }
}

impl Tracker {
    /// Sets the probe length per axis (and with it the spread a fit needs).
    pub fn set_probe(&mut self, probe: Vec2) {
        self.probe = probe;
        self.min_spread = probe[0].min(probe[1]) / 4.0;
    }

    /// Whether anything was seen or looked for yet.
    pub fn is_fresh(&self) -> bool {
        self.clean.is_empty() && self.partial.is_empty() && self.missing.is_empty()
    }

    /// The next command to learn the response while bringing the feature towards the
    /// centre of an image of size `view`. From a fresh start, one probe length along the
    /// first axis (the feature is usually in view at the start). Once two clean sightings
    /// span one direction, the move along it that they predict puts the feature nearest the
    /// centre, combined with a probe across it, short enough that the feature stays in view
    /// whichever way it goes (at the response measured along; either sign, then a third for
    /// a feature that left the image anyway): the probe makes progress and is seen.
    /// Otherwise [`Self::next_probe`], trying axis `prefer` first around a partial sighting.
    pub fn next_probe_towards(&self, start: Vec2, view: Vec2, prefer: Option<usize>) -> Vec2 {
        if self.is_fresh() {
            return self.clamp([start[0] + self.probe[0], start[1]]);
        }
        self.probe_across(view)
            .unwrap_or_else(|| self.next_probe_preferring(start, prefer))
    }

    fn probe_across(&self, view: Vec2) -> Option<Vec2> {
        let target = [view[0] / 2.0, view[1] / 2.0];
        let &(base, seen) = self.clean.last()?;
        let &(other, other_seen) = self
            .clean
            .iter()
            .max_by(|a, b| distance(a.0, base).total_cmp(&distance(b.0, base)))?;
        let span = distance(other, base);
        if span < self.min_spread {
            return None;
        }
        let along = [(other[0] - base[0]) / span, (other[1] - base[1]) / span];
        let response = [
            (other_seen[0] - seen[0]) / span,
            (other_seen[1] - seen[1]) / span,
        ];
        let strength = response[0].powi(2) + response[1].powi(2);
        if strength < 1e-12 {
            return None;
        }
        let probe = self.probe[0] * along[1].abs() + self.probe[1] * along[0].abs();
        let reach = 3.0 * probe.max(span);
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
        let landing = [
            seen[0] + travel * response[0],
            seen[1] + travel * response[1],
        ];
        let size = strength.sqrt();
        let sideways = [-response[1] / size, response[0] / size];
        let room = room(landing, sideways, view) - IN_VIEW_MARGIN_PX;
        let full = (room / (size * probe)).clamp(1.0 / 3.0, 1.0);
        [full, -full, full / 3.0, -full / 3.0]
            .into_iter()
            .map(|share| {
                let step = share * probe;
                self.clamp([
                    base[0] + travel * along[0] + step * across[0],
                    base[1] + travel * along[1] + step * across[1],
                ])
            })
            .find(|c| {
                let spread = (c[0] - base[0]) * across[0] + (c[1] - base[1]) * across[1];
                spread.abs() >= self.min_spread && !self.tried_within(*c, SAME_COMMAND)
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_an_exact_affine_map() {
        let truth = Affine {
            offset: [900.0, 500.0],
            gain: [[0.17, 0.012], [-0.01, -0.16]],
        };
        let points: Vec<(Vec2, Vec2)> =
            [[0.0, 0.0], [2000.0, 0.0], [0.0, 2000.0], [1500.0, -700.0]]
                .iter()
                .map(|&u| (u, truth.predict(u)))
                .collect();
        let fit = Affine::fit(&points, 100.0).unwrap();
        assert!(
            points
                .iter()
                .all(|(u, p)| distance(fit.predict(*u), *p) < 1e-9)
        );
        let u = fit.solve([960.0, 540.0]).unwrap();
        assert!(distance(truth.predict(u), [960.0, 540.0]) < 1e-9);
        assert!(Affine::fit(&points[..2], 100.0).is_none());
    }

    #[test]
    fn probes_an_unspanned_axis_next() {
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        tracker.add_clean([0.0, 0.0], [100.0, 100.0]);
        tracker.add_clean([1500.0, 0.0], [350.0, 100.0]);
        assert_eq!(tracker.next_probe([0.0, 0.0]), [1500.0, 1500.0]);
    }

    #[test]
    fn probes_across_while_centring_along_a_known_direction() {
        let mut tracker = Tracker::new([1500.0, 1500.0], [[-8000.0, 8000.0], [-6000.0, 6000.0]]);
        assert_eq!(
            tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], None),
            [1500.0, 0.0]
        );
        // 0.2 px per step along the first axis: 500 px short of the target is 2500 steps.
        tracker.add_clean([0.0, 0.0], [160.0, 540.0]);
        tracker.add_clean([1500.0, 0.0], [460.0, 540.0]);
        let next = tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], None);
        assert!(distance(next, [4000.0, 1500.0]) < 1e-6, "{next:?}");
        tracker.add_missing(next);
        let next = tracker.next_probe_towards([0.0, 0.0], [1920.0, 1080.0], None);
        assert!(distance(next, [4000.0, -1500.0]) < 1e-6, "{next:?}");
    }
}
