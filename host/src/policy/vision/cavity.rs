//! The cavity agent: the bright primary stays put and its saturated core marks the target;
//! the dim secondary is found in the difference between successive frames (it is the only
//! thing that moves with the in-coupler; rings, halo and ghosts cancel). Probes along each
//! axis (or an expanding search while it is off-screen) give an affine motor-to-image map;
//! the agent then commands a point a little off the target to check the map where it
//! matters, and declares done at the target the refined map gives.

use std::sync::Arc;

use optalign_optics::Frame;

use super::model::{Tracker, Vec2, distance};
use super::track::{BlobFilter, Sighting, sighting};
use crate::imaging::{find_beams, saturated_centre};
use crate::task::{Action, CavityLimits};

/// Probe length per axis, steps (about 200 px).
const PROBE: Vec2 = [1500.0, 1500.0];

/// Offset of the check point from the target, steps (the secondary clears the primary).
const CHECK_STEPS: f64 = 1200.0;

/// Within this distance of the primary's centre the secondary is (partly) hidden, px.
const HIDDEN_PX: f64 = 130.0;

/// A check sighting within this distance of the prediction confirms the map, px.
const CONFIRM_PX: f64 = 15.0;

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
    previous: Option<Arc<Frame>>,
    target: Option<Vec2>,
    last: Step,
    checks: usize,
}

impl CavityAgent {
    pub fn new(limits: &CavityLimits) -> Self {
        let range = limits.ranges.map(|r| [f64::from(r.min), f64::from(r.max)]);
        Self {
            tracker: Tracker::new(PROBE, range),
            command: [0.0; 2],
            before: [0.0; 2],
            previous: None,
            target: None,
            last: Step::Start,
            checks: 0,
        }
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Arc<Frame>, rejected: bool, remaining: usize) -> Action {
        let target = *self.target.get_or_insert_with(|| primary_centre(frame));
        let confirmed = if rejected {
            false
        } else {
            self.observe(frame, target)
        };
        self.previous = Some(frame.clone());
        let Some(model) = self.tracker.model() else {
            let u = if remaining <= 1 {
                self.command
            } else {
                self.tracker.next_probe([0.0, 0.0])
            };
            return self.send(u, Step::Probe, remaining <= 1);
        };
        let aim = model
            .solve(target)
            .map_or(self.command, |u| self.tracker.clamp(u));
        if confirmed || remaining <= 2 || self.checks >= 4 {
            return self.send(aim, Step::Check(None), true);
        }
        // Alternate the side of the check point so the fit sees the target from around it.
        let sides = [
            [CHECK_STEPS, 0.0],
            [0.0, CHECK_STEPS],
            [-CHECK_STEPS, 0.0],
            [0.0, -CHECK_STEPS],
        ];
        let side = sides[self.checks % sides.len()];
        let mut u = [aim[0] + side[0], aim[1] + side[1]];
        if self.tracker.clamp(u) != u {
            u = [aim[0] - side[0], aim[1] - side[1]];
        }
        self.checks += 1;
        self.send(u, Step::Check(Some(model.predict(u))), false)
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
            "target_px": self.target,
            "secondary": self.tracker.claims(self.command),
        })
    }

    /// Learns from the last move; true when a check point matched its prediction.
    fn observe(&mut self, frame: &Frame, target: Vec2) -> bool {
        let Some(before) = self.previous.take() else {
            return false;
        };
        if self.last == Step::Start {
            return false;
        }
        let visible = |c: Vec2| distance(c, target) > HIDDEN_PX;
        let filter = BlobFilter {
            accept: Some(&visible),
            companion: None,
        };
        let seen = sighting(&before, frame, &[], &[], false, &filter);
        self.tracker.record_move(self.before, self.command, seen);
        match (self.last, seen.appeared) {
            (
                Step::Check(Some(p)),
                Some(Sighting {
                    centre,
                    clean: true,
                }),
            ) => distance(p, centre) < CONFIRM_PX,
            _ => false,
        }
    }

    fn send(&mut self, u: Vec2, step: Step, done: bool) -> Action {
        self.before = self.command;
        self.command = self.tracker.clamp(u);
        self.last = step;
        Action::Cavity {
            command: self.command.map(|c| c.round() as i32),
            done,
        }
    }
}

/// The primary's centre: the saturated core, else the brightest region, else the centre.
fn primary_centre(frame: &Frame) -> Vec2 {
    saturated_centre(frame, 200)
        .or_else(|| find_beams(frame).first().map(|b| b.centre))
        .unwrap_or([
            f64::from(frame.width()) / 2.0,
            f64::from(frame.height()) / 2.0,
        ])
}
