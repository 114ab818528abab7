//! The Michelson agent: maps each mirror by probing one at a time, checks both beams apart
//! beside the centre, and is done once sure of both there. See docs/vision.md ("Michelson").

use optalign_optics::Frame;

use super::model::{Sighting, Tracker, Vec2, column_norm, distance, nearest_point};
use super::see::{Seen, View, motion};
use super::sight::{Scales, sight};
use super::tuning::{
    ALIKE_LIGHT, BORDER_RADII, CAUTIOUS_SHARE, CHECK_APART_RADII, DONE_CONFIDENCE, GRID_VIEW_SHARE,
    IN_VIEW_RADII, LANDS_WITHIN_PX, MICHELSON_APART_RADII, MICHELSON_MATCH_RADII,
    MICHELSON_PROBE_RADII, MICHELSON_SEARCH_SHARE, MIN_NOISE_PX, MIN_SPREAD_SHARE, PARK_SHARE,
    PARK_WHEN_SHARE, PROBE_GROWTH, PROBE_VIEW_SHARE, SAME_STEP, SEARCH_GRID_SHARE, TARGET_TURN,
    WHOLE_RADII,
};
use crate::imaging::Beam;
use crate::task::{Action, MichelsonLimits};

/// Search grid spacing per command axis, steps, moving the beam ≤ [`GRID_VIEW_SHARE`] of `size`.
fn search_grid(gain: [[f64; 2]; 2], size: Vec2) -> Vec2 {
    [0, 1].map(|axis| {
        (0..2)
            .map(|row| GRID_VIEW_SHARE * size[row] / gain[row][axis].abs().max(1e-9))
            .fold(f64::INFINITY, f64::min)
    })
}

/// What the last action was for.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Step {
    #[default]
    Start,
    /// Mirror `k` probed; the other beam, if parked in the move, went `parked.0` to `parked.1`.
    Probe {
        k: usize,
        parked: Option<(Vec2, Vec2)>,
    },
    /// Both beams placed apart near the centre; where the maps predicted them.
    Check { predicted: [Vec2; 2] },
    /// Both mirrors to their next blind-search points, neither beam seen: one image, two grids.
    Search { k: usize },
    /// Mirror `k` alone moved a little to tell whose is the beam a search showed (`appeared`).
    Attribute { k: usize, appeared: Beam },
    /// Both beams to the centre, unsure, the budget all but spent: stands, never declared done.
    Final,
}

/// The Michelson state machine.
#[derive(Default)]
pub struct MichelsonAgent {
    trackers: [Tracker; 2],
    /// Each mirror's command, steps per axis.
    command: [Vec2; 2],
    previous: Option<View>,
    /// Both mirrors' commands before the last action.
    before: [Vec2; 2],
    last: Step,
    checks: usize,
    /// The task's tolerance of the summed distance of the two beams from the centre, px.
    tolerance: f64,
    /// Mirrors a check did not find where their map put them: probed again until seen clean.
    refuted: [bool; 2],
    scales: Scales,
    /// A beam the last search showed, not yet told whose.
    appeared: Option<Beam>,
    /// Where the features that stayed put through the last probe are, px.
    stayed: Vec<Vec2>,
    /// The most light each beam showed clean and whole: a much fainter feature is not that beam.
    light: [Option<f64>; 2],
}

impl MichelsonAgent {
    pub fn new(limits: &MichelsonLimits) -> Self {
        let range = limits.ranges.map(|r| [f64::from(r.min), f64::from(r.max)]);
        let spans = range.map(|r| r[1] - r[0]);
        Self {
            trackers: [0, 2].map(|a| {
                let probe = [CAUTIOUS_SHARE * spans[a], CAUTIOUS_SHARE * spans[a + 1]];
                let mut tracker = Tracker::new(probe, [range[a], range[a + 1]]);
                tracker.min_spread = MIN_SPREAD_SHARE * probe[0].min(probe[1]);
                tracker
            }),
            tolerance: limits.success_error_px,
            ..Self::default()
        }
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Frame, rejected: bool, remaining: usize) -> Action {
        let view = View::new(frame);
        self.scales.learn_view(&view);
        let noise = self.scales.model_noise();
        for tracker in &mut self.trackers {
            tracker.noise = noise;
        }
        let confirmed = !rejected && self.observe(&view);
        self.before = self.command;
        let (centre, size) = (view.centre(), view.size());
        self.previous = Some(view);
        if matches!(self.last, Step::Final) {
            return self.send(Step::Final, false);
        }
        let unmapped = |k: &usize| self.trackers[*k].model().is_none() || self.refuted[*k];
        let next = (0..2)
            .filter(unmapped)
            .find(|&k| self.sighted(k))
            .or_else(|| (0..2).find(unmapped));
        if remaining <= 1 || (next.is_some() && remaining <= 3) {
            return self.finish(centre, false);
        }
        if let Some(k) = next {
            if let Some(appeared) = self.appeared.take() {
                return self.attribute(k, appeared);
            }
            self.scale_probe(k, size);
            let margin = IN_VIEW_RADII * self.scales.radius(k);
            let target = self.probe_target(k, centre, size);
            let u = self.trackers[k].next_probe_towards([0.0, 0.0], size, target, margin);
            if !self.sighted(k) && !self.sighted(1 - k) && !self.trackers[k].is_fresh() {
                return self.search(k, u);
            }
            return self.probe(k, u, centre);
        }
        if confirmed || remaining <= 2 {
            return self.finish(centre, confirmed);
        }
        self.check(centre, size)
    }

    /// What the agent believes, for the transcript: the phase and each mirror's tracker.
    pub fn claims(&self, done: bool) -> serde_json::Value {
        let phase = match (done, self.last) {
            (true, _) => "both beams to the centre, done".to_string(),
            (_, Step::Final) => "both beams to the centre, not sure, budget spent".to_string(),
            (_, Step::Start) => "start".to_string(),
            (_, Step::Probe { k, parked: None }) => format!("probe mirror {}", k + 1),
            (_, Step::Probe { k, parked: Some(_) }) => {
                format!("probe mirror {}, mirror {} parked", k + 1, 2 - k)
            }
            (_, Step::Check { .. }) => "check both beams apart near the centre".to_string(),
            (_, Step::Search { .. }) => "search both mirrors".to_string(),
            (_, Step::Attribute { k, .. }) => format!("tell whether the beam seen is {}", k + 1),
        };
        let mirrors = [0, 1].map(|k| self.trackers[k].claims(self.command[k]));
        serde_json::json!({
            "phase": phase,
            "mirrors": mirrors,
            "bench": self.scales.claims(),
        })
    }

    /// Learns from what the last action showed; true when a check confirmed both maps.
    fn observe(&mut self, view: &View) -> bool {
        let Some(before) = self.previous.take() else {
            return false;
        };
        self.stayed.clear();
        match self.last {
            Step::Start | Step::Final => {}
            Step::Probe { k, parked } => {
                self.refuted[k] &= !self.observe_probe(&before, view, k, parked)
            }
            Step::Check { predicted } => {
                let repeated = self.repeated();
                if repeated {
                    self.scales.learn_steady(&before, view);
                }
                return self.observe_check(view, predicted, repeated);
            }
            Step::Search { k } => self.observe_search(&before, view, k),
            Step::Attribute { k, appeared } => self.observe_attribute(&before, view, k, &appeared),
        }
        false
    }

    /// Learns from a move of mirror `k` alone; true when its beam was seen clean where it went.
    fn observe_probe(
        &mut self,
        before: &View,
        after: &View,
        k: usize,
        parked: Option<(Vec2, Vec2)>,
    ) -> bool {
        let j = 1 - k;
        let pairs = self.scales.learn_steady(before, after);
        self.stayed = pairs.iter().map(|&(_, i)| after.beams[i].centre).collect();
        let (old, new) = (self.before[k], self.command[k]);
        let expected = self.trackers[k].predict(new);
        let moved = motion(before, after, self.scales.steady(), expected, parked);
        let untried = !self.trackers[k].tried_within(old, SAME_STEP);
        let radius = self.scales.radius(j);
        let judge = |seen: Option<Seen>, view: &View, parked: Option<Vec2>, v: Vec2| {
            let seen = seen?;
            let other = parked.or_else(|| self.trackers[j].predict(v));
            let other = other.map(|p| (p, radius));
            Some(match sight(&seen.beam, view, &self.scales, k, other) {
                Sighting::Clean(c) | Sighting::Fitted(c) if !seen.whole => Sighting::Partial(c),
                other => other,
            })
        };
        let seen_to = judge(moved.to, after, parked.map(|p| p.1), self.command[j]);
        let seen_from = judge(moved.from, before, parked.map(|p| p.0), self.before[j]);
        self.adapt_probe(k, [seen_from, seen_to], distance(old, new), after);
        self.trackers[k].file(new, seen_to);
        if untried && let Some(s) = seen_from {
            self.trackers[k].file_before_move(old, s);
        }
        if let (Some(Sighting::Clean(_)), Some(s)) = (seen_to, moved.to) {
            self.scales.learn_shape(k, &s.beam, after);
            self.light[k] = Some(self.light[k].map_or(s.beam.signal, |l| l.max(s.beam.signal)));
        }
        if let Some(c) = parked.and_then(|(_, to)| self.find_near(after, j, to)) {
            self.trackers[j].add_clean(self.command[j], c);
        }
        self.trackers[k].estimate_band();
        matches!(seen_to, Some(Sighting::Clean(_) | Sighting::Fitted(_)))
    }

    /// Sizes mirror `k`'s next probes from what the last one showed of its beam.
    fn adapt_probe(&mut self, k: usize, seen: [Option<Sighting>; 2], step: f64, after: &View) {
        if step < SAME_STEP {
            return;
        }
        let tracker = &self.trackers[k];
        let span = tracker.shorter_span();
        let [lo, hi] = tracker.probe_bounds();
        let probe = tracker.probe;
        let scaled = |factor: f64| tracker.scaled_probe(factor);
        let length = match seen {
            [
                Some(Sighting::Clean(a) | Sighting::Fitted(a)),
                Some(Sighting::Clean(b) | Sighting::Fitted(b)),
            ] => {
                let response = distance(a, b) / step;
                let wanted = self.useful_move(k, after.size());
                if response > 0.0 {
                    [(wanted / response).clamp(lo, hi); 2]
                } else {
                    scaled(PROBE_GROWTH)
                }
            }
            [Some(Sighting::Clean(_) | Sighting::Fitted(_)), None] => scaled(1.0 / PROBE_GROWTH),
            [_, Some(Sighting::Partial(_))] => {
                [MICHELSON_SEARCH_SHARE * span; 2].map(|p| p.max(probe[0]))
            }
            [None, None] if !tracker.clean.is_empty() => {
                if tracker.model().is_none() && !self.still_in_view(k, after) {
                    // Out of view before and after: a longer probe would only stray farther.
                    probe
                } else {
                    scaled(PROBE_GROWTH)
                }
            }
            [None, None] => {
                // Never seen whole: big steps; on a grid once the other (alike) mount is mapped.
                let search = match self.trackers[1 - k].model() {
                    Some(other) => {
                        let side = after.shorter_side();
                        let grid = search_grid(other.gain, after.size())
                            .map(|g| g.clamp(2.0 * lo, 2.0 * span));
                        self.trackers[k].search_grid = Some(grid);
                        SEARCH_GRID_SHARE * side / column_norm(other.gain).max(1e-9)
                    }
                    None => (MICHELSON_SEARCH_SHARE * span).max(probe[0] * PROBE_GROWTH.sqrt()),
                };
                [search.clamp(lo, hi); 2]
            }
            _ => probe,
        };
        self.trackers[k].probe = length;
    }

    /// Where probes steer beam `k`: the `centre`, or, with [`Self::obstacle`] near it, a place in
    /// view [`MICHELSON_APART_RADII`] summed radii from it, lest the two beams stay merged.
    fn probe_target(&self, k: usize, centre: Vec2, size: Vec2) -> Vec2 {
        let Some((other, from)) = self.obstacle(k, centre) else {
            return centre;
        };
        let apart = MICHELSON_APART_RADII * (self.scales.radius(0) + self.scales.radius(1));
        if distance(other, centre) >= apart {
            return centre;
        }
        let margin = (WHOLE_RADII * self.scales.radius(k)).min(size[0].min(size[1]) / 2.0);
        let away = if distance(from, other) > self.scales.radius(k) {
            from
        } else {
            centre
        };
        let heading = (away[1] - other[1]).atan2(away[0] - other[0]);
        let inside = |p: Vec2| [0, 1].map(|a| p[a].clamp(margin, size[a] - margin));
        let point = |turn: f64| {
            let angle = heading + turn * TARGET_TURN;
            inside([
                other[0] + apart * angle.cos(),
                other[1] + apart * angle.sin(),
            ])
        };
        // Reachable targets first; if none is far enough, the reachable place farthest away.
        let tracker = &self.trackers[k];
        let map = tracker.steering_map();
        let reachable =
            |p: &Vec2| map.is_none_or(|m| m.solve(*p).is_some_and(|u| tracker.clamp(u) == u));
        let turns = (0..=6).flat_map(|i| [f64::from(i), -f64::from(i)]);
        let targets: Vec<Vec2> = turns.map(point).filter(reachable).collect();
        if let Some(&p) = targets.iter().find(|p| distance(**p, other) >= apart - 1.0) {
            return p;
        }
        let corners = map.map(|m| {
            let [[x0, x1], [y0, y1]] = tracker.range;
            [x0, (x0 + x1) / 2.0, x1]
                .into_iter()
                .flat_map(|x| [y0, (y0 + y1) / 2.0, y1].map(|y| inside(m.predict([x, y]))))
                .collect::<Vec<_>>()
        });
        targets
            .into_iter()
            .chain(corners.into_iter().flatten())
            .max_by(|a, b| distance(*a, other).total_cmp(&distance(*b, other)))
            .unwrap_or(centre)
    }

    /// What beam `k` must not be steered onto, and where it was last seen, px: the other beam;
    /// else, if `k` was last seen merged (not clean), the nearest feature that stayed put.
    fn obstacle(&self, k: usize, centre: Vec2) -> Option<(Vec2, Vec2)> {
        let tracker = &self.trackers[k];
        let latest = tracker.latest()?;
        let j = 1 - k;
        if let Some((_, _, landing)) = self.parking(k, centre) {
            return Some((landing, latest.image));
        }
        if !self.refuted[j]
            && let Some(p) = self.trackers[j].predict(self.command[j])
        {
            return Some((p, latest.image));
        }
        // Near a border a partial sighting is cut, not merged.
        let border = BORDER_RADII * self.scales.radius(k);
        let at_border = (0..2).any(|a| centre[a] - (latest.image[a] - centre[a]).abs() < border);
        let merged = tracker.partial.iter().any(|s| s.order == latest.order) && !at_border;
        let stayed = nearest_point(self.stayed.iter().copied(), latest.image);
        merged.then_some((stayed.unwrap_or(latest.image), latest.image))
    }

    fn still_in_view(&self, k: usize, view: &View) -> bool {
        let reach = MICHELSON_MATCH_RADII * self.scales.radius(k);
        self.trackers[k].latest().is_some_and(|last| {
            view.beams
                .iter()
                .any(|b| distance(b.centre, last.image) < reach)
        })
    }

    /// How far a probe should move beam `k` on an image of `size`, px.
    fn useful_move(&self, k: usize, size: Vec2) -> f64 {
        (MICHELSON_PROBE_RADII * self.scales.radius(k)).min(PROBE_VIEW_SHARE * size[0].min(size[1]))
    }

    /// Learns from a check (`repeated`: replacing the last's); true if both maps held and are sure.
    fn observe_check(&mut self, view: &View, predicted: [Vec2; 2], repeated: bool) -> bool {
        let found = [0, 1].map(|k| self.find_near(view, k, predicted[k]));
        if let [Some(a), Some(b)] = found
            && a == b
        {
            return false;
        }
        let believed =
            (0..2).all(|k| found[k].is_some_and(|c| self.trackers[k].believes(self.command[k], c)));
        let before_refit = self.trackers.clone();
        let mut relearned = false;
        for (k, seen) in found.iter().enumerate() {
            self.refuted[k] |= seen.is_none();
            if let Some(c) = seen {
                if repeated {
                    self.trackers[k].forget_clean(self.before[k]);
                }
                self.trackers[k].add_clean(self.command[k], *c);
                relearned |= self.trackers[k].estimate_band();
            }
        }
        // A dead band newly found changes every prediction: it is checked first.
        believed && !relearned && self.sure_at_centre(view.centre(), &before_refit)
    }

    /// Whether both beams land within half the tolerance of `centre`, each at the root of
    /// [`DONE_CONFIDENCE`], by the models now and `before` the last check.
    fn sure_at_centre(&self, centre: Vec2, before: &[Tracker; 2]) -> bool {
        let each = DONE_CONFIDENCE.sqrt();
        (0..2).all(|k| {
            let tracker = &self.trackers[k];
            tracker
                .command_for(centre, self.command[k])
                .is_some_and(|u| {
                    tracker.settled_at(&before[k], u, centre, self.tolerance / 2.0, each)
                })
        })
    }

    /// Whether the maps say the last command moved neither beam by [`MIN_NOISE_PX`]: only jitter.
    fn repeated(&self) -> bool {
        (0..2).all(|k| {
            let predict = |u| self.trackers[k].predict(u);
            let [from, to] = [self.before[k], self.command[k]].map(predict);
            from.zip(to)
                .is_some_and(|(a, b)| distance(a, b) < MIN_NOISE_PX)
        })
    }

    /// Beam `k`'s clean centre nearest `point` (match radius), bright enough by [`ALIKE_LIGHT`].
    fn find_near(&self, view: &View, k: usize, point: Vec2) -> Option<Vec2> {
        let radius = self.scales.radius(k);
        let matching = view
            .beams
            .iter()
            .filter(|b| self.light[k].is_none_or(|light| b.signal >= ALIKE_LIGHT[0] * light))
            .filter_map(|b| sight(b, view, &self.scales, k, None).fit_centre())
            .filter(|c| distance(*c, point) < MICHELSON_MATCH_RADII * radius);
        nearest_point(matching, point)
    }

    /// Sizes a fresh mirror's probes at the other's response (mounts of a kind respond alike).
    fn scale_probe(&mut self, k: usize, size: Vec2) {
        let known = self.trackers[1 - k].model();
        let Some(known) = known.filter(|_| self.trackers[k].is_fresh()) else {
            return;
        };
        let wanted = self.useful_move(k, size);
        let [lo, hi] = self.trackers[k].probe_bounds();
        let probe = [0, 1].map(|axis| {
            let response = known.gain[0][axis].hypot(known.gain[1][axis]);
            (wanted / response.max(1e-9)).clamp(lo, hi)
        });
        self.trackers[k].probe = probe;
    }

    /// Moves mirror `k` to `u`, parking the other beam in the same move ([`Self::parking`]).
    fn probe(&mut self, k: usize, u: Vec2, centre: Vec2) -> Action {
        let parking = self.parking(k, centre);
        self.set_mirror(k, self.trackers[k].clamp(u));
        let parked = parking.map(|(v, now, landing)| {
            self.set_mirror(1 - k, v);
            (now, landing)
        });
        self.send(Step::Probe { k, parked }, false)
    }

    /// Where the other, mapped mirror goes while `k` is probed, if its beam is near the centre:
    /// its command, where its beam is now and where it lands (away from the probed beam).
    fn parking(&self, k: usize, centre: Vec2) -> Option<(Vec2, Vec2, Vec2)> {
        let j = 1 - k;
        let now = self.trackers[j].predict(self.command[j])?;
        let probed_x = self.trackers[k]
            .clean
            .last()
            .or(self.trackers[k].partial.last())
            .map_or(centre[0], |s| s.image[0]);
        let side = if probed_x > centre[0] { -1.0 } else { 1.0 };
        let width = 2.0 * centre[0];
        let spot = [centre[0] + side * PARK_SHARE * width, centre[1]];
        if distance(now, centre) >= PARK_WHEN_SHARE * width {
            return None;
        }
        let v = self.trackers[j].command_for(spot, self.command[j])?;
        let landing = self.trackers[j].predict(v)?;
        (distance(landing, spot) < self.scales.radius(j)).then_some((v, now, landing))
    }

    fn sighted(&self, k: usize) -> bool {
        self.trackers[k].latest().is_some()
    }

    /// Moves mirror `k` to `u` and the other to its own next search point, at one probe length.
    fn search(&mut self, k: usize, u: Vec2) -> Action {
        let j = 1 - k;
        let (probe, grid) = (self.trackers[k].probe, self.trackers[k].search_grid);
        self.trackers[j].probe = probe;
        self.trackers[j].search_grid = self.trackers[j].search_grid.or(grid);
        self.set_mirror(k, self.trackers[k].clamp(u));
        self.set_mirror(j, self.trackers[j].next_probe([0.0, 0.0]));
        self.send(Step::Search { k }, false)
    }

    /// Learns from a search: nothing seen is a miss for both; a beam seen is attributed next.
    fn observe_search(&mut self, before: &View, after: &View, k: usize) {
        if let Some(seen) = motion(before, after, self.scales.steady(), None, None).to {
            self.appeared = Some(seen.beam);
            return;
        }
        self.observe_probe(before, after, k, None);
        let j = 1 - k;
        self.trackers[j].add_missing(self.command[j]);
    }

    /// Moves mirror `k` alone a cautious step towards its range's middle: the beam moves if `k`'s.
    fn attribute(&mut self, k: usize, appeared: Beam) -> Action {
        let now = self.command[k];
        let [low, high] = self.trackers[k].range[0];
        let step = CAUTIOUS_SHARE * (high - low);
        let middle = (low + high) / 2.0;
        let towards_middle = if now[0] > middle { -step } else { step };
        self.set_mirror(k, self.trackers[k].clamp([now[0] + towards_middle, now[1]]));
        self.send(Step::Attribute { k, appeared }, false)
    }

    /// Learns from an attribution move: a beam it moved is `k`'s, else the search's is the other's.
    fn observe_attribute(&mut self, before: &View, after: &View, k: usize, appeared: &Beam) {
        if self.observe_probe(before, after, k, None) || self.sighted(k) {
            return;
        }
        let j = 1 - k;
        self.trackers[k].add_missing(self.before[k]);
        let sighting = sight(appeared, before, &self.scales, j, None);
        self.trackers[j].file(self.command[j], Some(sighting));
    }

    fn set_mirror(&mut self, k: usize, u: Vec2) {
        self.trackers[k].moved(self.command[k], u);
        self.command[k] = u;
    }

    /// Both beams apart on either side of the centre, where each is seen whole.
    fn check(&mut self, centre: Vec2, size: Vec2) -> Action {
        let radius = 0.5 * (self.scales.radius(0) + self.scales.radius(1));
        let wanted = CHECK_APART_RADII[self.checks.min(CHECK_APART_RADII.len() - 1)] * radius;
        let [ax, ay] = [0, 1].map(|axis| {
            wanted
                .min(size[axis] / 2.0 - WHOLE_RADII * radius)
                .max(radius)
        });
        let layouts = [
            [[-ax, 0.0], [ax, 0.0]],
            [[0.0, -ay], [0.0, ay]],
            [[ax, 0.0], [-ax, 0.0]],
            [[0.0, ay], [0.0, -ay]],
        ];
        // From the next layout on, the first landing both beams as wanted, else the first solved.
        let mut candidates = (self.checks..self.checks + layouts.len()).filter_map(|i| {
            let targets = layouts[i % layouts.len()].map(|d| [centre[0] + d[0], centre[1] + d[1]]);
            let [a, b] = [0, 1].map(|k| self.trackers[k].command_for(targets[k], self.command[k]));
            let solved = [a?, b?];
            let lands = |k: usize| self.trackers[k].predict(solved[k]);
            let within =
                (0..2).all(|k| lands(k).is_some_and(|p| distance(p, targets[k]) < LANDS_WITHIN_PX));
            Some((solved, within))
        });
        let first = candidates.next();
        let chosen = first
            .filter(|c| c.1)
            .or_else(|| candidates.find(|c| c.1))
            .or(first);
        self.checks += 1;
        let Some((solved, _)) = chosen else {
            return self.finish(centre, false);
        };
        let predicted = [0, 1].map(|k| {
            self.set_mirror(k, solved[k]);
            self.trackers[k].predict(solved[k]).unwrap_or(centre)
        });
        self.send(Step::Check { predicted }, false)
    }

    /// Both beams to the centre: done when `sure`, else it stands to the end ([`Step::Final`]).
    fn finish(&mut self, centre: Vec2, sure: bool) -> Action {
        for k in 0..2 {
            if let Some(u) = self.trackers[k].command_for(centre, self.command[k]) {
                self.set_mirror(k, u);
            }
        }
        self.send(Step::Final, sure)
    }

    fn send(&mut self, step: Step, done: bool) -> Action {
        self.last = step;
        let [[a, b], [c, d]] = self.command.map(|u| u.map(|v| v.round() as i32));
        Action::Michelson {
            command: [a, b, c, d],
            done,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::synthetic::Scene;
    use crate::policy::vision::model::Affine;

    fn truths() -> [Affine; 2] {
        [
            Affine {
                offset: [700.0, 400.0],
                gain: [[0.17, 0.012], [-0.01, -0.16]],
            },
            Affine {
                offset: [1200.0, 700.0],
                gain: [[-0.165, -0.015], [0.012, 0.155]],
            },
        ]
    }

    /// A dark 1920 x 1080 frame to draw beams on, the camera's background at 8 gray levels.
    fn scene() -> Scene {
        Scene::new(1920, 1080).background(8.0, [0.0, 0.0])
    }

    /// An agent that saw each beam at six commands, where `truths` put it, off by
    /// `scatter(i)` px.
    fn agent_with(truths: [Affine; 2], scatter: impl Fn(usize) -> f64) -> MichelsonAgent {
        let mut agent = MichelsonAgent::new(&MichelsonLimits::default());
        let commands = [
            [0.0, 0.0],
            [900.0, 0.0],
            [900.0, 800.0],
            [0.0, 800.0],
            [-700.0, 300.0],
            [400.0, -500.0],
        ];
        for (k, truth) in truths.iter().enumerate() {
            for (i, u) in commands.into_iter().enumerate() {
                agent.set_mirror(k, u);
                let p = truth.predict(u);
                let e = scatter(i);
                agent.trackers[k].add_clean(u, [p[0] + e, p[1] - e]);
            }
        }
        agent
    }

    #[test]
    fn a_check_does_not_take_faint_light_near_a_prediction_for_the_beam() {
        let mut agent = agent_with(truths(), |_| 0.0);
        // Both mirrors at the origin command: the maps put beam 1 at (700, 400), beam 2 at
        // (1200, 700). Each beam was seen whole before, at most with the light of this one.
        let alone = View::new(
            &scene()
                .gaussian([700.0, 400.0], 40.0, 150.0)
                .noise(2.5, 1)
                .frame(),
        );
        for k in 0..2 {
            agent.scales.learn_size(k, 40.0);
            agent.light[k] = Some(alone.beams[0].signal);
        }
        // Beam 1 where its map puts it; beam 2 gone, a faint broad glow beside its place.
        let frame = scene()
            .gaussian([700.0, 400.0], 40.0, 150.0)
            .gaussian([1225.0, 690.0], 90.0, 5.0)
            .noise(2.5, 2)
            .frame();
        let view = View::new(&frame);
        assert_eq!(
            view.beams.len(),
            2,
            "the glow is detected: {:?}",
            view.beams
        );
        let beam = agent.find_near(&view, 0, [700.0, 400.0]);
        assert!(
            beam.is_some_and(|c| distance(c, [700.0, 400.0]) < 1.0),
            "{beam:?}"
        );
        assert_eq!(agent.find_near(&view, 1, [1200.0, 700.0]), None);
        // Without the beam's light known, the glow would pass for it.
        agent.light[1] = None;
        assert!(agent.find_near(&view, 1, [1200.0, 700.0]).is_some());
    }

    #[test]
    fn repeated_checks_measure_the_jitter_that_moved_beams_overstated() {
        let mut agent = agent_with(truths(), |_| 0.0);
        let at = [0, 1].map(|k| truths()[k].predict(agent.command[k]));
        let frame = |shift: f64, seed: u64| {
            let moved = |p: Vec2| [p[0] + shift, p[1]];
            let scene = scene().gaussian(moved(at[0]), 40.0, 150.0);
            scene
                .gaussian(moved(at[1]), 40.0, 140.0)
                .noise(2.5, seed)
                .frame()
        };
        for k in 0..2 {
            agent.scales.learn_size(k, 40.0);
        }
        // Both beams moved 5 px between two frames, within what may pass for jitter before
        // any was measured: 6 px of jitter learned where there is none.
        agent
            .scales
            .learn_steady(&View::new(&frame(0.0, 1)), &View::new(&frame(5.0, 2)));
        assert!(agent.scales.model_noise() > 3.0, "{:?}", agent.scales);
        let check = |agent: &mut MichelsonAgent, seed: u64| {
            agent.previous = Some(View::new(&frame(0.0, seed)));
            agent.last = Step::Check { predicted: at };
            agent.observe(&View::new(&frame(0.0, seed + 1)));
        };
        // A check after a command the maps say moves beam 1 by 1.7 px: not a repeat.
        agent.before = agent.command;
        agent.before[0][0] += 10.0;
        check(&mut agent, 3);
        assert!(agent.scales.model_noise() > 3.0, "{:?}", agent.scales);
        // Checks at commands 2 steps apart (0.34 px): the beams stay within the frames' own
        // noise. Each replaces the one before, so that one place does not outweigh the probes.
        let (origin, sightings) = (agent.command, agent.trackers[0].clean.len());
        for (seed, shift) in [(5, 0.0), (7, 2.0), (9, 0.0)] {
            agent.before = agent.command;
            agent.command[0][0] = origin[0][0] + shift;
            check(&mut agent, seed);
        }
        assert!(agent.scales.model_noise() < 1.0, "{:?}", agent.scales);
        assert_eq!(agent.trackers[0].clean.len(), sightings);
    }

    #[test]
    fn a_search_grid_tiles_the_image_along_each_axis() {
        // Axis 1 moves the beam 0.68 px per step horizontally, axis 2 0.64 px vertically.
        let gain = [[0.68, 0.0], [0.0, -0.64]];
        let grid = search_grid(gain, [1920.0, 1080.0]);
        assert!((grid[0] * 0.68 - GRID_VIEW_SHARE * 1920.0).abs() < 1e-6);
        assert!((grid[1] * 0.64 - GRID_VIEW_SHARE * 1080.0).abs() < 1e-6);
        // Rotated 45 degrees, each axis moves the beam along both image axes: the shorter
        // side limits the spacing.
        let diagonal = [[0.5, -0.5], [0.5, 0.5]];
        let grid = search_grid(diagonal, [1920.0, 1080.0]);
        assert!((grid[0] - GRID_VIEW_SHARE * 1080.0 / 0.5).abs() < 1e-6);
        assert!((grid[1] - GRID_VIEW_SHARE * 1080.0 / 0.5).abs() < 1e-6);
    }

    #[test]
    fn done_when_both_models_are_sure_at_the_centre_and_a_refit_moved_nothing() {
        let centre = [960.0, 540.0];
        let agent = agent_with(truths(), |_| 0.0);
        let same = agent.trackers.clone();
        assert!(agent.sure_at_centre(centre, &same));
        // The models before the last sightings put the final command elsewhere (a refit
        // changed the map): not settled.
        let mut wrong = truths();
        wrong[1].gain[0][0] *= 1.2;
        let earlier = agent_with(wrong, |_| 0.0).trackers;
        assert!(!agent.sure_at_centre(centre, &earlier));
    }

    #[test]
    fn a_bench_that_scatters_beyond_the_tolerance_is_not_done() {
        let centre = [960.0, 540.0];
        // Exact but for tens of pixels of scatter from one command to the next (a screw's
        // pitch error): a new command meets as much, more than the task's tolerance.
        let agent = agent_with(truths(), |i| if i % 2 == 0 { 30.0 } else { -30.0 });
        let same = agent.trackers.clone();
        assert!(!agent.sure_at_centre(centre, &same));
        // A scatter of a pixel is well within it.
        let agent = agent_with(truths(), |i| if i % 2 == 0 { 1.0 } else { -1.0 });
        let same = agent.trackers.clone();
        assert!(agent.sure_at_centre(centre, &same));
    }
}
