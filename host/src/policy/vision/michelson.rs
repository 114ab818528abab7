//! The Michelson agent: learns each mirror's motor-to-image response by moving one mirror
//! at a time and watching which beam moves (the other stays put in the frame difference),
//! searching outwards for a beam that is off-screen, then brings mirror 1's beam to the
//! image centre with mirror 2's beam parked aside, swaps the two to check mirror 2's, and
//! finally commands both to the centre, where they overlap in fringes.

use std::sync::Arc;

use optalign_optics::Frame;

use super::model::{Tracker, Vec2, distance};
use super::track::{Sighting, sighting};
use crate::imaging::{BeamSpot, find_beams};
use crate::task::{Action, MichelsonLimits};

/// Probe length per axis, steps (about 420 px: a beam clears its own old footprint).
const PROBE: Vec2 = [2500.0, 2500.0];

/// Where a beam waits while the other is checked at the centre, px from the centre.
const PARK_PX: f64 = 450.0;

/// Beams predicted closer than this overlap, px.
const OVERLAP_PX: f64 = 350.0;

/// A sighting farther than this from the prediction is some other feature, px.
const MATCH_PX: f64 = 40.0;

/// What the last action was for.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Step {
    /// Nothing moved yet.
    Start,
    /// One mirror moved to learn its response.
    Probe(usize),
    /// `centred` went to the centre, the other beam to a parking place.
    Check { centred: usize },
}

/// The Michelson state machine.
pub struct MichelsonAgent {
    trackers: [Tracker; 2],
    command: [f64; 4],
    previous: Option<(Arc<Frame>, Vec<BeamSpot>)>,
    /// Both mirrors' commands before the last action.
    before: [Vec2; 2],
    last: Step,
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
            trackers: [0, 2].map(|a| Tracker::new(PROBE, [range(a), range(a + 1)])),
            command: [0.0; 4],
            previous: None,
            before: [[0.0; 2]; 2],
            last: Step::Start,
        }
    }

    fn mirror(&self, k: usize) -> Vec2 {
        [self.command[2 * k], self.command[2 * k + 1]]
    }

    /// The next action for a new frame; `rejected` means nothing moved.
    pub fn decide(&mut self, frame: &Arc<Frame>, rejected: bool, remaining: usize) -> Action {
        let spots = find_beams(frame);
        if !rejected {
            self.observe(frame, &spots);
        }
        self.previous = Some((frame.clone(), spots));
        let centre = [
            f64::from(frame.width()) / 2.0,
            f64::from(frame.height()) / 2.0,
        ];
        if remaining <= 1 {
            return self.finish(centre);
        }
        let next = (0..2).find(|&k| self.trackers[k].model().is_none());
        if let Some(k) = next {
            if remaining <= 3 {
                return self.finish(centre);
            }
            let u = self.trackers[k].next_probe([0.0, 0.0]);
            return self.send(k, u, Step::Probe(k));
        }
        match self.last {
            Step::Check { centred: 0 } if remaining > 2 => self.check(1, centre),
            Step::Check { .. } => self.finish(centre),
            _ => self.check(0, centre),
        }
    }

    /// Learns from the change the last action made.
    fn observe(&mut self, frame: &Frame, spots: &[BeamSpot]) {
        let Some((before, before_spots)) = self.previous.take() else {
            return;
        };
        match self.last {
            Step::Start => {}
            Step::Probe(k) => {
                let (old, new) = (self.before[k], self.mirror(k));
                let seen = sighting(&before, frame, &before_spots, spots, true, |_| true);
                record(&mut self.trackers[k], new, seen.appeared);
                let unmeasured = self.trackers[k]
                    .clean
                    .iter()
                    .all(|(u, _)| distance(*u, old) >= 1.0);
                if let (true, Some(s)) = (unmeasured, seen.vanished) {
                    record(&mut self.trackers[k], old, Some(s));
                }
            }
            Step::Check { .. } => {
                let predicted: Vec<Option<Vec2>> = (0..2)
                    .map(|k| self.trackers[k].model().map(|m| m.predict(self.mirror(k))))
                    .collect();
                if let [Some(a), Some(b)] = predicted[..] {
                    if distance(a, b) < OVERLAP_PX {
                        return;
                    }
                    for (k, p) in [a, b].into_iter().enumerate() {
                        let near = spots
                            .iter()
                            .filter(|s| !s.clipped && distance(s.centre, p) < MATCH_PX)
                            .min_by(|x, y| distance(x.centre, p).total_cmp(&distance(y.centre, p)));
                        if let Some(s) = near {
                            let u = self.mirror(k);
                            self.trackers[k].add_clean(u, s.centre);
                        }
                    }
                }
            }
        }
    }

    fn send(&mut self, k: usize, u: Vec2, step: Step) -> Action {
        self.before = [self.mirror(0), self.mirror(1)];
        let u = self.trackers[k].clamp(u);
        self.command[2 * k] = u[0];
        self.command[2 * k + 1] = u[1];
        self.last = step;
        self.action(false)
    }

    /// Mirror `centred`'s beam to the centre, the other beam parked aside.
    fn check(&mut self, centred: usize, centre: Vec2) -> Action {
        self.before = [self.mirror(0), self.mirror(1)];
        let other = 1 - centred;
        if let Some(u) = self.aim(centred, centre) {
            self.command[2 * centred] = u[0];
            self.command[2 * centred + 1] = u[1];
        }
        let parks = [
            [PARK_PX, 0.0],
            [-PARK_PX, 0.0],
            [0.0, PARK_PX],
            [0.0, -PARK_PX],
        ];
        if let Some(u) = parks.iter().find_map(|d| {
            let u = self.aim(other, [centre[0] + d[0], centre[1] + d[1]])?;
            (self.trackers[other].clamp(u) == u).then_some(u)
        }) {
            self.command[2 * other] = u[0];
            self.command[2 * other + 1] = u[1];
        }
        self.last = Step::Check { centred };
        self.action(false)
    }

    /// The command putting mirror `k`'s beam at `point`, within range.
    fn aim(&self, k: usize, point: Vec2) -> Option<Vec2> {
        let u = self.trackers[k].model()?.solve(point)?;
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

/// Files a sighting of a moved beam with its tracker.
fn record(tracker: &mut Tracker, command: Vec2, seen: Option<Sighting>) {
    match seen {
        Some(Sighting {
            centre,
            clean: true,
        }) => tracker.add_clean(command, centre),
        Some(Sighting {
            centre,
            clean: false,
        }) => tracker.add_partial(command, centre),
        None => tracker.add_missing(command),
    }
}
