//! The Michelson agent: learns each mirror's motor-to-image response by moving one mirror
//! at a time and watching which beam moves (the other stays put in the frame difference).
//! Each probe after the first also steers the beam towards the centre along what is already
//! known, so it stays in view; beams cut by the border are located by a spot fit. While
//! the second mirror is probed, the first mirror's beam is parked out of the way. With
//! both maps known it places the two beams a little apart on either side of the centre,
//! where both are seen whole: when they land where the maps predicted it commands both to
//! the centre (where they overlap in fringes) and declares done; otherwise it refits and
//! checks again.

use std::sync::Arc;

use optalign_optics::Frame;

use super::model::{Tracker, Vec2, distance};
use super::track::{BlobFilter, sighting, trusted_centre};
use crate::imaging::{BeamSpot, find_beams};
use crate::task::{Action, MichelsonLimits};

/// First probe length per axis, steps (about 420 px at the lab's response).
const FIRST_PROBE: Vec2 = [2500.0, 2500.0];

/// Once one mirror's response is known, the other's probes aim to move its beam this far,
/// px: well clear of its own footprint, yet likely to stay in view.
const PROBE_PX: f64 = 400.0;

/// Probe lengths derived from a measured response stay within these bounds, steps.
const PROBE_BOUNDS: Vec2 = [400.0, 5000.0];

/// While one mirror is probed, the other's beam (once its map is known) waits this far
/// left or right of the centre, on the side away from the probed beam, px.
const PARK_PX: f64 = 680.0;

/// A known beam closer than this to the centre is parked before the other is probed, px.
const PARK_WHEN_PX: f64 = 560.0;

/// The spread of probe commands a fit needs, as a share of the probe length: fitted spot
/// centres are good to a pixel, so a short spread still gives a well-conditioned map.
const MIN_SPREAD_SHARE: f64 = 0.125;

/// Half the separation of the two beams at successive checks, px.
const CHECK_APART_PX: [f64; 3] = [220.0, 300.0, 380.0];

/// A beam a check did not find goes this many times the other beam's distance from the
/// centre to the other side of it.
const RELOCATE_SHARE: f64 = 1.5;

/// A checked beam within this distance of its prediction confirms the map, px.
const CONFIRM_PX: f64 = 3.0;

/// A spot farther than this from a beam's prediction is not that beam, px.
const MATCH_PX: f64 = 120.0;

/// A partial sighting this close to a border was cut by it, px.
const BORDER_PX: f64 = 80.0;

/// What the last action was for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    /// Nothing moved yet.
    Start,
    /// Mirror `k` moved to learn its response; the other beam, when it was moved out of
    /// the way at the same time, went from `parked.0` to `parked.1` (predicted).
    Probe {
        k: usize,
        parked: Option<(Vec2, Vec2)>,
    },
    /// Both beams placed apart near the centre; where the maps predicted them.
    Check { predicted: [Vec2; 2] },
}

/// The Michelson state machine.
pub struct MichelsonAgent {
    trackers: [Tracker; 2],
    command: [f64; 4],
    previous: Option<(Arc<Frame>, Vec<BeamSpot>)>,
    /// Both mirrors' commands before the last action.
    before: [Vec2; 2],
    last: Step,
    checks: usize,
    /// A beam the last check did not find where its map put it.
    missed: Option<usize>,
}

impl MichelsonAgent {
    pub fn new(limits: &MichelsonLimits) -> Self {
        let range = |a: usize| {
            [
                f64::from(limits.ranges[a].min),
                f64::from(limits.ranges[a].max),
            ]
        };
        Self {
            trackers: [0, 2].map(|a| {
                let mut tracker = Tracker::new(FIRST_PROBE, [range(a), range(a + 1)]);
                tracker.min_spread = MIN_SPREAD_SHARE * FIRST_PROBE[0].min(FIRST_PROBE[1]);
                tracker
            }),
            command: [0.0; 4],
            previous: None,
            before: [[0.0; 2]; 2],
            last: Step::Start,
            checks: 0,
            missed: None,
        }
    }

    fn mirror(&self, k: usize) -> Vec2 {
        [self.command[2 * k], self.command[2 * k + 1]]
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Arc<Frame>, rejected: bool, remaining: usize) -> Action {
        let spots = find_beams(frame);
        let confirmed = !rejected && self.observe(frame, &spots);
        self.previous = Some((frame.clone(), spots));
        let centre = [
            f64::from(frame.width()) / 2.0,
            f64::from(frame.height()) / 2.0,
        ];
        if remaining <= 1 {
            return self.finish(centre);
        }
        if let Some(k) = (0..2).find(|&k| self.trackers[k].model().is_none()) {
            if remaining <= 3 {
                return self.finish(centre);
            }
            self.scale_probe(k);
            let prefer = self.trackers[k]
                .partial
                .last()
                .and_then(|(_, seen)| border_axis(*seen, centre));
            let view = [2.0 * centre[0], 2.0 * centre[1]];
            let u = self.trackers[k].next_probe_towards([0.0, 0.0], view, prefer);
            return self.probe(k, u, centre);
        }
        if confirmed || remaining <= 2 {
            return self.finish(centre);
        }
        match self.missed {
            Some(k) => self.relocate(k, centre),
            None => self.check(centre),
        }
    }

    /// What the agent believes after its last decision, for the transcript: what the
    /// action was for and, per mirror, its sightings, fitted response and where it expects
    /// that mirror's beam (px, x right, y down).
    pub fn claims(&self, done: bool) -> serde_json::Value {
        let phase = match (done, self.last) {
            (true, _) => "both beams to the centre, done".to_string(),
            (_, Step::Start) => "start".to_string(),
            (_, Step::Probe { k, parked: None }) => format!("probe mirror {}", k + 1),
            (_, Step::Probe { k, parked: Some(_) }) => {
                format!("probe mirror {}, mirror {} parked", k + 1, 2 - k)
            }
            (_, Step::Check { .. }) => "check both beams apart near the centre".to_string(),
        };
        let mirrors: Vec<_> = (0..2)
            .map(|k| self.trackers[k].claims(self.mirror(k)))
            .collect();
        serde_json::json!({ "phase": phase, "mirrors": mirrors })
    }

    /// Learns from what the last action showed; true when a check confirmed both maps.
    fn observe(&mut self, frame: &Frame, spots: &[BeamSpot]) -> bool {
        let Some((before, before_spots)) = self.previous.take() else {
            return false;
        };
        match self.last {
            Step::Start => false,
            Step::Probe { k, parked } => {
                let filter = BlobFilter {
                    accept: None,
                    companion: parked,
                };
                let seen = sighting(&before, frame, &before_spots, spots, true, &filter);
                let (old, new) = (self.before[k], self.mirror(k));
                self.trackers[k].record_move(old, new, seen);
                if let Some((_, to)) = parked
                    && let Some(c) = nearest_trusted(spots, frame, to)
                {
                    let u = self.mirror(1 - k);
                    self.trackers[1 - k].add_clean(u, c);
                }
                false
            }
            Step::Check { predicted } => {
                let found = predicted.map(|p| nearest_trusted(spots, frame, p));
                if let [Some(a), Some(b)] = found
                    && a == b
                {
                    return false;
                }
                self.missed = found.iter().position(Option::is_none);
                for (k, seen) in found.iter().enumerate() {
                    if let Some(c) = seen {
                        let u = self.mirror(k);
                        self.trackers[k].add_clean(u, *c);
                    }
                }
                found
                    .iter()
                    .zip(predicted)
                    .all(|(seen, p)| seen.is_some_and(|c| distance(c, p) < CONFIRM_PX))
            }
        }
    }

    /// A fresh mirror's probes move its beam about [`PROBE_PX`] at the other mirror's
    /// measured response (mounts of one kind respond alike).
    fn scale_probe(&mut self, k: usize) {
        let Some(known) = self.trackers[1 - k].model() else {
            return;
        };
        if !self.trackers[k].is_fresh() {
            return;
        }
        let probe = [0, 1].map(|axis| {
            let response = known.gain[0][axis].hypot(known.gain[1][axis]);
            (PROBE_PX / response.max(1e-9)).clamp(PROBE_BOUNDS[0], PROBE_BOUNDS[1])
        });
        self.trackers[k].set_probe(probe);
        self.trackers[k].min_spread = MIN_SPREAD_SHARE * probe[0].min(probe[1]);
    }

    /// Moves mirror `k` to `u`; the other beam, when its map is known and it sits where the
    /// probed beam is being steered, goes aside in the same move.
    fn probe(&mut self, k: usize, u: Vec2, centre: Vec2) -> Action {
        self.before = [self.mirror(0), self.mirror(1)];
        let u = self.trackers[k].clamp(u);
        self.command[2 * k] = u[0];
        self.command[2 * k + 1] = u[1];
        let j = 1 - k;
        let mut parked = None;
        if let Some(model) = self.trackers[j].local_model() {
            let now = model.predict(self.mirror(j));
            let probed_x = self.trackers[k]
                .clean
                .last()
                .or(self.trackers[k].partial.last())
                .map_or(centre[0], |(_, p)| p[0]);
            let side = if probed_x > centre[0] { -1.0 } else { 1.0 };
            let spot = [centre[0] + side * PARK_PX, centre[1]];
            if distance(now, centre) < PARK_WHEN_PX
                && let Some(v) = model.solve(spot)
                && self.trackers[j].clamp(v) == v
            {
                self.command[2 * j] = v[0];
                self.command[2 * j + 1] = v[1];
                parked = Some((now, model.predict(v)));
            }
        }
        self.last = Step::Probe { k, parked };
        self.action(false)
    }

    /// Both beams a little apart on either side of the centre, where each is seen whole.
    fn check(&mut self, centre: Vec2) -> Action {
        let apart = CHECK_APART_PX[self.checks.min(CHECK_APART_PX.len() - 1)];
        let layouts = [
            [[-apart, 0.0], [apart, 0.0]],
            [[0.0, -apart], [0.0, apart]],
            [[apart, 0.0], [-apart, 0.0]],
            [[0.0, apart], [0.0, -apart]],
        ];
        let first = self.checks % layouts.len();
        let mut chosen = None;
        for layout in layouts.iter().cycle().skip(first).take(layouts.len()) {
            let targets = layout.map(|d| [centre[0] + d[0], centre[1] + d[1]]);
            let solved = [0, 1].map(|k| self.trackers[k].local_model()?.solve(targets[k]));
            if let [Some(a), Some(b)] = solved {
                let within = [a, b]
                    .iter()
                    .enumerate()
                    .all(|(k, u)| self.trackers[k].clamp(*u) == *u);
                if within || chosen.is_none() {
                    chosen = Some([a, b]);
                }
                if within {
                    break;
                }
            }
        }
        self.checks += 1;
        self.before = [self.mirror(0), self.mirror(1)];
        let Some(solved) = chosen else {
            return self.finish(centre);
        };
        let mut predicted = [[0.0; 2]; 2];
        for (k, u) in solved.into_iter().enumerate() {
            let u = self.trackers[k].clamp(u);
            self.command[2 * k] = u[0];
            self.command[2 * k + 1] = u[1];
            if let Some(model) = self.trackers[k].local_model() {
                predicted[k] = model.predict(u);
            }
        }
        self.last = Step::Check { predicted };
        self.action(false)
    }

    /// Moves mirror `k` alone to the far side of the centre from the other beam: the frame
    /// difference then shows which spot is its beam, wherever its map put it.
    fn relocate(&mut self, k: usize, centre: Vec2) -> Action {
        self.missed = None;
        let other = self.trackers[1 - k]
            .local_model()
            .map_or(centre, |m| m.predict(self.mirror(1 - k)));
        let target = [
            centre[0] + RELOCATE_SHARE * (centre[0] - other[0]),
            centre[1] + RELOCATE_SHARE * (centre[1] - other[1]),
        ];
        let u = self.aim(k, target).unwrap_or(self.mirror(k));
        self.before = [self.mirror(0), self.mirror(1)];
        self.command[2 * k] = u[0];
        self.command[2 * k + 1] = u[1];
        self.last = Step::Probe { k, parked: None };
        self.action(false)
    }

    /// The command putting mirror `k`'s beam at `point`, within range.
    fn aim(&self, k: usize, point: Vec2) -> Option<Vec2> {
        let u = self.trackers[k].local_model()?.solve(point)?;
        Some(self.trackers[k].clamp(u))
    }

    /// Both beams to the centre, done.
    fn finish(&mut self, centre: Vec2) -> Action {
        for k in 0..2 {
            if let Some(u) = self.aim(k, centre) {
                self.command[2 * k] = u[0];
                self.command[2 * k + 1] = u[1];
            }
        }
        self.action(true)
    }

    fn action(&self, done: bool) -> Action {
        Action::Michelson {
            command: self.command.map(|c| c.round() as i32),
            done,
        }
    }
}

/// The trusted spot centre nearest `point`, within [`MATCH_PX`].
fn nearest_trusted(spots: &[BeamSpot], frame: &Frame, point: Vec2) -> Option<Vec2> {
    spots
        .iter()
        .filter_map(|s| trusted_centre(s, frame))
        .filter(|c| distance(*c, point) < MATCH_PX)
        .min_by(|a, b| distance(*a, point).total_cmp(&distance(*b, point)))
}

/// The axis that moves a beam seen at `point` away from the border it is cut by: 1
/// (vertical) at the top or bottom, 0 at the left or right (nominally, axis 1 of a mount
/// tilts horizontally and axis 2 vertically; the agent still measures signs and scales).
fn border_axis(point: Vec2, centre: Vec2) -> Option<usize> {
    let gap = |axis: usize| centre[axis] - (point[axis] - centre[axis]).abs();
    let (horizontal, vertical) = (gap(0), gap(1));
    if vertical < BORDER_PX && vertical < horizontal {
        Some(1)
    } else if horizontal < BORDER_PX {
        Some(0)
    } else {
        None
    }
}
