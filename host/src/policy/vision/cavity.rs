//! The cavity agent: steers the dim secondary, seen in frame differences, onto the fixed
//! primary's core, mapping the in-coupler by probes and checks. See docs/vision.md ("Cavity").

use optalign_optics::Frame;

use super::model::{Sighting, Tracker, Vec2, distance, rings};
use super::see::{Seen, View, alike, motion_in};
use super::sight::{Scales, default_radius, sight};
use super::tuning::{
    APART_RADII, CAUTIOUS_SHARE, CAVITY_MATCH_RADII, CAVITY_PROBE_RADII, CAVITY_SEARCH_SHARE,
    CAVITY_TOLERANCE_RADII, CHECK_CLEARANCE_RADII, CORE_REACH_RADII, DONE_CONFIDENCE, HIDDEN_RADII,
    MIN_CHANGE_RADIUS_PX, PRIMARY, PRIMARY_CORE_SHARE, PROBE_GROWTH, RESOLVED_RADII, SAME_STEP,
    SEARCH_LEVELS, SEARCH_TRIED_SHARE, SECONDARY,
};
use crate::imaging::{core_centre, core_radius, nearest, registered_changes_sized, scene_shift};
use crate::task::{Action, CavityLimits};

/// What the last action was for (a probe before the first: every decision sends one).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Step {
    #[default]
    Probe,
    /// A point near the target; the prediction made for it.
    Check(Option<Vec2>),
    /// The secondary to the target, unsure, the budget all but spent: stands, never done.
    Final,
}

/// The cavity state machine.
#[derive(Default)]
pub struct CavityAgent {
    tracker: Tracker,
    command: Vec2,
    before: Vec2,
    previous: Option<View>,
    primary: Option<Primary>,
    scales: Scales,
    last: Step,
    /// Whether the last check found the secondary at all.
    last_check_seen: bool,
    checks: usize,
}

impl CavityAgent {
    pub fn new(limits: &CavityLimits) -> Self {
        let range = limits.ranges.map(|r| [f64::from(r.min), f64::from(r.max)]);
        Self {
            tracker: Tracker::new(range.map(|r| CAUTIOUS_SHARE * (r[1] - r[0])), range),
            ..Self::default()
        }
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Frame, rejected: bool, remaining: usize) -> Action {
        let view = View::new(frame);
        self.scales.learn_view(&view);
        let primary = *self.primary.get_or_insert_with(|| Primary::measure(&view));
        let (target, primary_radius) = (primary.centre, primary.radius);
        if self.scales.known_radius(PRIMARY).is_none() {
            self.scales.learn_size(PRIMARY, primary_radius);
        }
        self.tracker.noise = self.scales.model_noise();
        let before_refit = self.tracker.clone();
        let confirmed = !rejected && self.observe(&view, primary);
        self.previous = Some(view);
        let modelled = self.tracker.model().is_some();
        if matches!(self.last, Step::Final) || (!modelled && remaining <= 1) {
            return self.send(self.command, Step::Final, false);
        }
        if !modelled {
            let u = if self.tracker.latest().is_none() && !self.tracker.missing.is_empty() {
                self.search()
            } else {
                self.tracker.next_probe([0.0, 0.0])
            };
            return self.send(u, Step::Probe, false);
        }
        let aim = self
            .tracker
            .command_for(target, self.command)
            .unwrap_or(self.command);
        let tolerance = CAVITY_TOLERANCE_RADII * self.scales.radius(SECONDARY);
        let sure = confirmed
            && self
                .tracker
                .settled_at(&before_refit, aim, target, tolerance, DONE_CONFIDENCE);
        if sure || remaining <= 2 {
            return self.send(aim, Step::Final, sure);
        }
        if matches!(self.last, Step::Check(_)) && !self.last_check_seen {
            // The check lost the secondary: probe again from its last clean sighting.
            let from = self
                .tracker
                .clean
                .last()
                .map_or(self.command, |s| s.command);
            return self.send(self.tracker.next_probe(from), Step::Probe, false);
        }
        // Alternate the side of the check point so the fit sees the target from around it.
        let radius = self.scales.radius(SECONDARY);
        let clear = HIDDEN_RADII * primary_radius + CHECK_CLEARANCE_RADII * radius;
        let sides = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]];
        let point = |side: Vec2| [target[0] + clear * side[0], target[1] + clear * side[1]];
        let solve = |side: Vec2| self.tracker.command_for(point(side), self.command);
        let side = sides[self.checks % sides.len()];
        let mut u = solve(side).unwrap_or(aim);
        if self.tracker.clamp(u) != u {
            u = solve([-side[0], -side[1]]).unwrap_or(aim);
        }
        self.checks += 1;
        self.send(u, Step::Check(self.tracker.predict(u)), false)
    }

    /// What the agent believes, for the transcript: phase, target, primary and secondary tracker.
    pub fn claims(&self, done: bool) -> serde_json::Value {
        let phase = match (done, self.last) {
            (true, _) => "secondary to the primary, done",
            (_, Step::Probe) => "probe",
            (_, Step::Check(_)) => "check beside the primary",
            (_, Step::Final) => "secondary to the primary, not sure, budget spent",
        };
        serde_json::json!({
            "phase": phase,
            "target_px": self.primary.map(|p| p.centre),
            "primary_radius_px": self.primary.map(|p| p.radius),
            "primary_core_radius_px": self.primary.map(|p| p.core),
            "secondary": self.tracker.claims(self.command),
            "bench": self.scales.claims(),
        })
    }

    /// The next search command for a secondary never seen: two rings around the start, then ever
    /// finer grids over the range (a large response shows it only in a small patch, anywhere).
    fn search(&self) -> Vec2 {
        let step = self.tracker.spans().map(|s| CAVITY_SEARCH_SHARE * s);
        let untried = |u: Vec2, spacing: Vec2| {
            !self
                .tracker
                .tried_within(u, SEARCH_TRIED_SHARE * spacing[0].min(spacing[1]))
        };
        if let Some(u) = rings([0.0; 2], step, 1..=2)
            .into_iter()
            .map(|u| self.tracker.clamp(u))
            .find(|&u| untried(u, step))
        {
            return u;
        }
        let mut half = step;
        for _ in 0..SEARCH_LEVELS {
            half = half.map(|s| s / 2.0);
            let indices = |axis: usize| {
                let [lo, hi] = self.tracker.range[axis];
                (lo / half[axis]).floor() as i64..=(hi / half[axis]).ceil() as i64
            };
            // Each point, and whether it is an edge midpoint (an index even).
            let mut points: Vec<(bool, Vec2)> = indices(0)
                .flat_map(|i| indices(1).map(move |j| [i, j]))
                .filter(|[i, j]| i % 2 != 0 || j % 2 != 0)
                .map(|[i, j]| {
                    let u = [i as f64 * half[0], j as f64 * half[1]];
                    (i % 2 == 0 || j % 2 == 0, self.tracker.clamp(u))
                })
                .collect();
            let far = |u: Vec2| (u[0] / step[0]).hypot(u[1] / step[1]);
            points.sort_by(|(a, u), (b, v)| a.cmp(b).then(far(*u).total_cmp(&far(*v))));
            if let Some((_, u)) = points.into_iter().find(|&(_, u)| untried(u, half)) {
                return u;
            }
        }
        self.tracker.next_probe([0.0, 0.0])
    }

    /// Learns from the last move; true when a check point matched its prediction.
    fn observe(&mut self, view: &View, primary: Primary) -> bool {
        let (target, primary_radius) = (primary.centre, primary.radius);
        let Some(before) = self.previous.take() else {
            return false;
        };
        self.scales.learn_steady(&before, view);
        let expected = self.tracker.predict(self.command);
        // The primary carries its rings, halo and ghosts: where it jittered, they went too.
        let shift = nearest(&before.beams, target)
            .filter(|b| distance(b.centre, target) < primary_radius)
            .map_or([0.0, 0.0], |b| {
                scene_shift(&before.picture, &view.picture, b, PRIMARY_CORE_SHARE)
            });
        let radius = self.scales.radius(SECONDARY);
        // At its own size: a faint secondary in heavy noise stands out only averaged over it.
        let changes = registered_changes_sized(&before.picture, &view.picture, shift, radius);
        let steady = self.scales.steady();
        let moved = motion_in(&changes, &before, view, steady, expected, None);
        let hidden = HIDDEN_RADII * primary_radius;
        // Outside the primary or clear of its core (a saturated core hides changes); near the map.
        let outside = |s: &Seen| {
            let off = distance(s.change.centre, target);
            distance(s.beam.centre, target) > hidden || off - s.change.size() > primary.core
        };
        let expected_near = |centre: Vec2| {
            expected.is_none_or(|p| distance(centre, p) < CAVITY_MATCH_RADII * radius.max(hidden))
        };
        let like_secondary = |s: &Seen| s.change.size() >= MIN_CHANGE_RADIUS_PX;
        let appeared = moved
            .to
            .filter(|s| outside(s) && expected_near(s.beam.centre) && like_secondary(s));
        let vanished = moved.from.filter(|s| {
            outside(s) && like_secondary(s) && appeared.is_none_or(|a| alike(&a.change, &s.change))
        });
        if let (Some(a), Some(v)) = (appeared, vanished)
            && distance(a.beam.centre, v.beam.centre)
                <= RESOLVED_RADII * a.beam.size().max(v.beam.size())
        {
            // Moved too little to tell where it went: a longer probe next time.
            self.tracker.probe = self.tracker.scaled_probe(PROBE_GROWTH);
            return false;
        }
        let other = Some((target, primary_radius));
        // Moved clear of its other place, the change is the secondary alone: no halo pulls it.
        let apart = matches!((appeared, vanished), (Some(a), Some(v))
            if distance(a.change.centre, v.change.centre)
                > APART_RADII * a.change.size().max(v.change.size()));
        let judge = |seen: &Seen, view: &View| {
            let change = apart.then(|| sight(&seen.change, view, &self.scales, SECONDARY, other));
            match change {
                Some(change @ (Sighting::Clean(_) | Sighting::Fitted(_))) => change,
                _ if seen.whole => sight(&seen.beam, view, &self.scales, SECONDARY, other),
                _ => Sighting::Partial(seen.beam.centre),
            }
        };
        let seen_to = appeared.map(|s| judge(&s, view));
        let seen_from = vanished.map(|s| judge(&s, &before));
        // A check is judged before it joins the model: does the model believe it?
        let believed =
            matches!(seen_to, Some(Sighting::Clean(c)) if self.tracker.believes(self.command, c));
        let untried = !self.tracker.tried_within(self.before, SAME_STEP);
        self.tracker.file(self.command, seen_to);
        if let (true, Some(v)) = (untried, seen_from) {
            self.tracker.file_before_move(self.before, v);
        }
        if let (true, Some(Sighting::Clean(_)), Some(a), Some(v)) =
            (apart, seen_to, appeared, vanished)
            && !a.beam.clipped
        {
            self.scales.learn_size(SECONDARY, a.change.size());
            let step = distance(self.before, self.command);
            if !(step < SAME_STEP || self.tracker.model().is_some()) {
                let response = distance(v.beam.centre, a.beam.centre) / step;
                let length = CAVITY_PROBE_RADII * a.change.size() / response.max(1e-9);
                let [lo, hi] = self.tracker.probe_bounds();
                self.tracker.probe = [length.clamp(lo, hi); 2];
            }
        }
        self.tracker.estimate_band();
        let Step::Check(predicted) = self.last else {
            return false;
        };
        self.last_check_seen = seen_to.and_then(Sighting::fit_centre).is_some();
        predicted.is_some() && believed
    }

    fn send(&mut self, u: Vec2, step: Step, done: bool) -> Action {
        self.before = self.command;
        let u = self.tracker.clamp(u);
        self.tracker.moved(self.command, u);
        self.command = u;
        self.last = step;
        Action::Cavity {
            command: self.command.map(|c| c.round() as i32),
            done,
        }
    }
}

/// The primary: where it is, how large, and how large its bright core.
#[derive(Clone, Copy, Debug)]
struct Primary {
    /// The centre of its bright core (faint ghosts on its halo do not pull it), px.
    centre: Vec2,
    /// Its second-moment radius, px.
    radius: f64,
    /// Radius of the disc as large as its light above [`PRIMARY_CORE_SHARE`] of its peak, px.
    core: f64,
}

impl Primary {
    /// The brightest beam of the first frame, else a default disc at the image's centre.
    fn measure(view: &View) -> Self {
        let Some(b) = view.beams.first() else {
            let radius = default_radius(view.shorter_side());
            return Self {
                centre: view.centre(),
                radius,
                core: radius,
            };
        };
        let centre = core_centre(&view.picture, b, PRIMARY_CORE_SHARE).unwrap_or(b.centre);
        Self {
            centre,
            radius: b.size(),
            core: core_radius(
                &view.picture,
                centre,
                b,
                PRIMARY_CORE_SHARE,
                CORE_REACH_RADII,
            ),
        }
    }
}
