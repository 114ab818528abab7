//! The cavity agent: the bright primary stays put and its intensity centroid marks the
//! target; the dim secondary is found in the difference between successive frames (it is
//! the only thing that moves with the in-coupler; rings, halo, ghosts and stray light
//! cancel, and the laser's power drift is taken out first). Nothing about the bench is
//! assumed beyond the command ranges: the first probe is a cautious share of the range,
//! later ones are sized from the measured response to move the secondary a useful number
//! of its own radii; while it has not been seen, a search widens in big steps across the
//! range. Probes along each axis give an affine motor-to-image map; the agent then
//! commands a point just outside the primary's footprint to check the map where it
//! matters, and declares done at the target the refined map gives.

use optalign_optics::Frame;

use super::model::{SAME_STEP, Sighting, Tracker, Vec2, distance};
use super::see::View;
use crate::imaging::{Beam, changes};
use crate::task::{Action, CavityLimits};

/// The first probe moves an axis by this share of its command range.
const CAUTIOUS_SHARE: f64 = 1.0 / 32.0;

/// While the secondary has not been seen, the search steps by this share of the range.
const SEARCH_SHARE: f64 = 0.25;

/// Probe lengths stay within these shares of the command range.
const PROBE_SHARES: Vec2 = [1.0 / 64.0, 1.0 / 3.0];

/// A probe aims to move the secondary this many of its radii.
const PROBE_RADII: f64 = 4.0;

/// A change whose appearing and vanishing parts are closer than this many radii is a beam
/// that moved too little to measure: the probe grows by [`PROBE_GROWTH`].
const RESOLVED_RADII: f64 = 2.0;
const PROBE_GROWTH: f64 = 3.0;

/// Within this many primary radii of the target the secondary is (partly) hidden.
const HIDDEN_RADII: f64 = 1.9;

/// The check point sits this many secondary radii outside the hidden zone.
const CHECK_CLEARANCE_RADII: f64 = 1.5;

/// A check sighting within this many secondary radii of the prediction confirms the map
/// (or within the position noise, when that is larger).
const CONFIRM_RADII: f64 = 0.4;

/// A change farther than this many radii from the prediction is not the secondary.
const MATCH_RADII: f64 = 3.0;

/// Checks before the agent settles for its best map.
const MAX_CHECKS: usize = 4;

/// What the last action was for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    Start,
    Probe,
    /// A point near the target; the prediction made for it.
    Check(Option<Vec2>),
}

/// The cavity state machine.
pub struct CavityAgent {
    tracker: Tracker,
    command: Vec2,
    before: Vec2,
    previous: Option<View>,
    /// The primary's centre and radius, px, measured on the first frame.
    primary: Option<(Vec2, f64)>,
    /// The secondary's radius, px, once seen.
    secondary_radius: Option<f64>,
    last: Step,
    checks: usize,
    spans: Vec2,
}

impl CavityAgent {
    pub fn new(limits: &CavityLimits) -> Self {
        let range = limits.ranges.map(|r| [f64::from(r.min), f64::from(r.max)]);
        let spans = range.map(|r| r[1] - r[0]);
        Self {
            tracker: Tracker::new(spans.map(|s| CAUTIOUS_SHARE * s), range),
            command: [0.0; 2],
            before: [0.0; 2],
            previous: None,
            primary: None,
            secondary_radius: None,
            last: Step::Start,
            checks: 0,
            spans,
        }
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Frame, rejected: bool, remaining: usize) -> Action {
        let view = View::new(frame);
        let (target, primary_radius) = *self.primary.get_or_insert_with(|| primary(&view));
        let confirmed = !rejected && self.observe(&view, target, primary_radius);
        self.previous = Some(view);
        let Some(_) = self.tracker.model() else {
            let u = if remaining <= 1 {
                self.command
            } else if self.tracker.clean.is_empty()
                && self.tracker.partial.is_empty()
                && !self.tracker.missing.is_empty()
            {
                self.search()
            } else {
                self.tracker.next_probe([0.0, 0.0])
            };
            return self.send(u, Step::Probe, remaining <= 1);
        };
        let aim = self
            .tracker
            .command_for(target, self.command)
            .unwrap_or(self.command);
        if confirmed || remaining <= 2 || self.checks >= MAX_CHECKS {
            return self.send(aim, Step::Check(None), true);
        }
        // Alternate the side of the check point so the fit sees the target from around it.
        let radius = self.secondary_radius.unwrap_or(primary_radius / 2.0);
        let clear = HIDDEN_RADII * primary_radius + CHECK_CLEARANCE_RADII * radius;
        let sides = [[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]];
        let point = |side: Vec2| [target[0] + clear * side[0], target[1] + clear * side[1]];
        let side = sides[self.checks % sides.len()];
        let mut u = self
            .tracker
            .command_for(point(side), self.command)
            .unwrap_or(aim);
        if self.tracker.clamp(u) != u {
            u = self
                .tracker
                .command_for(point([-side[0], -side[1]]), self.command)
                .unwrap_or(aim);
        }
        self.checks += 1;
        let dir = [0, 1].map(|a| {
            let step = u[a] - self.command[a];
            if step.abs() >= SAME_STEP {
                step.signum()
            } else {
                self.tracker.dir[a]
            }
        });
        let predicted = self.tracker.predict(u, dir);
        self.send(u, Step::Check(predicted), false)
    }

    /// What the agent believes after its last decision, for the transcript: what the
    /// action was for, the target (the primary's centre, px) and its secondary tracker's
    /// sightings, fitted response and where it expects the secondary.
    pub fn claims(&self, done: bool) -> serde_json::Value {
        let phase = match (done, self.last) {
            (true, _) => "secondary to the primary, done",
            (_, Step::Start) => "start",
            (_, Step::Probe) => "probe",
            (_, Step::Check(_)) => "check beside the primary",
        };
        serde_json::json!({
            "phase": phase,
            "target_px": self.primary.map(|p| p.0),
            "primary_radius_px": self.primary.map(|p| p.1),
            "secondary_radius_px": self.secondary_radius,
            "secondary": self.tracker.claims(self.command),
        })
    }

    /// The next command of the search for a secondary never seen: rings around the start
    /// in steps of a large share of the range, halving the step once a ring is done.
    fn search(&self) -> Vec2 {
        let mut step = self.spans.map(|s| SEARCH_SHARE * s);
        for _ in 0..4 {
            let ring = [
                [1.0, 0.0],
                [-1.0, 0.0],
                [0.0, 1.0],
                [0.0, -1.0],
                [1.0, 1.0],
                [-1.0, 1.0],
                [1.0, -1.0],
                [-1.0, -1.0],
            ];
            for multiple in [1.0, 2.0] {
                for d in ring {
                    let u = self
                        .tracker
                        .clamp([d[0] * step[0] * multiple, d[1] * step[1] * multiple]);
                    if !self.tracker.tried_within(u, 0.25 * step[0].min(step[1])) {
                        return u;
                    }
                }
            }
            step = step.map(|s| s / 2.0);
        }
        self.tracker.next_probe([0.0, 0.0])
    }

    /// Learns from the last move; true when a check point matched its prediction.
    fn observe(&mut self, view: &View, target: Vec2, primary_radius: f64) -> bool {
        let Some(before) = self.previous.take() else {
            return false;
        };
        if self.last == Step::Start {
            return false;
        }
        let moved = changes(&before.picture, &view.picture);
        let hidden = HIDDEN_RADII * primary_radius;
        let visible = |b: &&Beam| distance(b.centre, target) > hidden;
        let expected = self.tracker.predict_here(self.command);
        let radius = self.secondary_radius.unwrap_or(primary_radius / 2.0);
        let pick = |blobs: &[Beam]| -> Option<Beam> {
            let blobs = blobs.iter().filter(visible);
            match expected {
                Some(p) => blobs
                    .filter(|b| distance(b.centre, p) < MATCH_RADII * radius.max(b.size()))
                    .min_by(|a, b| distance(a.centre, p).total_cmp(&distance(b.centre, p)))
                    .copied(),
                None => blobs.max_by(|a, b| a.signal.total_cmp(&b.signal)).copied(),
            }
        };
        let appeared = pick(&moved.appeared);
        let vanished = pick(&moved.vanished);
        let resolved = match (appeared, vanished) {
            (Some(a), Some(v)) => {
                distance(a.centre, v.centre) > RESOLVED_RADII * a.size().max(v.size())
            }
            _ => true,
        };
        if !resolved {
            // Moved too little to tell where it went: a longer probe next time.
            let [lo, hi] = [0, 1].map(|i| PROBE_SHARES[i] * self.spans[0].min(self.spans[1]));
            let probe = self.tracker.probe.map(|p| (p * PROBE_GROWTH).clamp(lo, hi));
            self.tracker.set_probe(probe);
            return false;
        }
        let judge = |b: &Beam| {
            if b.clipped || !b.localised {
                Sighting::Partial(b.centre)
            } else {
                Sighting::Clean(b.centre)
            }
        };
        let untried = !self.tracker.tried_within(self.before, SAME_STEP);
        self.tracker
            .file(self.command, appeared.as_ref().map(judge));
        if let (true, Some(v)) = (untried, vanished.as_ref()) {
            self.tracker.file_before_move(self.before, judge(v));
        }
        if let Some(b) = appeared.filter(|b| !b.clipped) {
            self.secondary_radius = Some(b.size());
            self.size_probe(b.size(), vanished.as_ref(), &b);
        }
        self.tracker.estimate_lost_motion();
        match (self.last, appeared.map(|b| judge(&b))) {
            (Step::Check(Some(p)), Some(Sighting::Clean(centre))) => {
                distance(p, centre)
                    < (CONFIRM_RADII * radius)
                        .max(3.0 * view.beams.first().map_or(0.0, |b| b.uncertainty))
            }
            _ => false,
        }
    }

    /// Sizes later probes from the response one probe showed (the secondary moved from
    /// `vanished` to `appeared`).
    fn size_probe(&mut self, radius: f64, vanished: Option<&Beam>, appeared: &Beam) {
        let Some(v) = vanished else {
            return;
        };
        let step = distance(self.before, self.command);
        if step < SAME_STEP || self.tracker.model().is_some() {
            return;
        }
        let response = distance(v.centre, appeared.centre) / step;
        let [lo, hi] = [0, 1].map(|i| PROBE_SHARES[i] * self.spans[0].min(self.spans[1]));
        let length = (PROBE_RADII * radius / response.max(1e-9)).clamp(lo, hi);
        self.tracker.set_probe([length, length]);
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

/// The primary: the brightest beam in the first frame (its centroid, saturated core and
/// all, and its radius), else the image centre.
fn primary(view: &View) -> (Vec2, f64) {
    view.beams
        .first()
        .map(|b| (b.centre, b.size()))
        .unwrap_or((view.centre(), 0.05 * view.size()[0].min(view.size()[1])))
}
