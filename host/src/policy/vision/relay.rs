//! The relay agent: aligns the mirrors in order along the beam. For mirror m it measures at
//! the near station of m's outgoing segment, where a tilt moves the spot little, learns
//! the mirror's response there by probing (searching outwards when the spot is off the
//! sensor or speckled), centres the spot, then moves to the far station, where the same
//! tilt moves the spot about ten times as far, and centres it there with the scaled
//! response, refined by Broyden updates. Light lost at the far station sends the camera
//! back to the near station. At C8, with a centred localised spot, it declares done.

use optalign_optics::{Frame, Station};

use super::model::{Affine, Tracker, Vec2, distance};
use crate::imaging::{BeamSpot, find_beams};
use crate::task::{RelayAction, RelayLimits};

/// Probe length per tilt axis at the near station, steps (about 66 px at C1).
const PROBE: Vec2 = [2000.0, 2000.0];

/// Probe length for learning the near response once a spot shows, steps (about 70 px at C1).
const NEAR_PROBE: f64 = 2500.0;

/// Longest single tilt at the near station, steps (about 200 px at C1).
const NEAR_REACH: f64 = 6000.0;

/// Expected spot travel at 1 mm from a mirror, px per step (twice 0.027 rad per 4096 steps,
/// 10 um pixels, less for the vertical axis of a 45 degree mirror): a floor for probe
/// responses shrunk by clipping.
const PX_PER_STEP_MM: f64 = 0.0009;

/// Distance of each station from the mirror before it, mm: near stations 25 mm after their
/// mirror, far ones just before the next mirror (C8 well along the output).
const STATION_MM: [f64; 8] = [25.0, 254.4, 25.0, 178.2, 25.0, 254.4, 25.0, 300.0];

/// A spot this close to the image centre is centred, px.
const CENTRED_PX: f64 = 10.0;

/// Upstream far stations only need the beam well inside the next mirror, px.
const PASS_PX: f64 = 20.0;

/// What the agent is doing for the current mirror.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Phase {
    /// Going to, or working at, the near station.
    Near,
    /// Working at the far station.
    Far,
}

/// The relay state machine.
pub struct RelayAgent {
    limits: RelayLimits,
    cumulative: [i32; 8],
    station: usize,
    mirror: usize,
    phase: Phase,
    near: Tracker,
    /// The current mirror's tilt when its alignment began (the centre of any search).
    near_start: Vec2,
    /// Near-station probes of the current mirror: tilt and spot centroid (clean or not).
    near_probes: Vec<(Vec2, Vec2, bool)>,
    /// The near station's response, px per step, once probed.
    near_gain: Option<[[f64; 2]; 2]>,
    /// The near-station spot before the last tilt and the tilt, for the Broyden update.
    near_last: Option<(Vec2, Vec2)>,
    /// The last tilt at which the near station showed the spot.
    near_seen: Option<Vec2>,
    /// The far station's response, px per step.
    far_gain: Option<[[f64; 2]; 2]>,
    /// The far-station spot before the last tilt and the tilt, for the Broyden update.
    far_last: Option<(Vec2, Vec2)>,
    far_dark: usize,
    last: Option<RelayAction>,
}

impl RelayAgent {
    pub fn new(limits: &RelayLimits) -> Self {
        Self {
            limits: limits.clone(),
            cumulative: [0; 8],
            station: 7,
            mirror: 0,
            phase: Phase::Near,
            near: new_tracker(limits),
            near_start: [0.0; 2],
            near_probes: Vec::new(),
            near_gain: None,
            near_last: None,
            near_seen: None,
            far_gain: None,
            far_last: None,
            far_dark: 0,
            last: None,
        }
    }

    fn tilt_of(&self, m: usize) -> Vec2 {
        [
            f64::from(self.cumulative[2 * m]),
            f64::from(self.cumulative[2 * m + 1]),
        ]
    }

    /// The next action for a new frame; `rejected` means nothing happened.
    pub fn decide(&mut self, frame: &Frame, rejected: bool, remaining: usize) -> RelayAction {
        if !rejected {
            self.apply_last();
        }
        let spot = best_spot(frame);
        let centre = [
            f64::from(frame.width()) / 2.0,
            f64::from(frame.height()) / 2.0,
        ];
        let near_station = 2 * self.mirror;
        let far_station = near_station + 1;
        if remaining <= 1 {
            return self.act(if self.station == 7 {
                RelayAction::Done
            } else {
                measure(7)
            });
        }
        if remaining <= 2 && self.station != 7 {
            return self.act(measure(7));
        }
        match self.phase {
            Phase::Near => {
                if self.station != near_station {
                    return self.act(measure(near_station));
                }
                self.near_phase(spot, centre, near_station)
            }
            Phase::Far => {
                if self.station != far_station {
                    return self.act(measure(far_station));
                }
                let gain = self.far_gain.unwrap_or([[1.0, 0.0], [0.0, 1.0]]);
                let Some(s) = spot else {
                    return self.far_lost(gain, centre);
                };
                let gain = broyden(gain, self.far_last, s.centre);
                self.far_gain = Some(gain);
                let tolerance = if self.mirror == 3 {
                    CENTRED_PX
                } else {
                    PASS_PX
                };
                if s.localised && !s.clipped && distance(s.centre, centre) < tolerance {
                    if self.mirror == 3 {
                        return self.act(RelayAction::Done);
                    }
                    self.mirror += 1;
                    self.phase = Phase::Near;
                    self.near = new_tracker(&self.limits);
                    self.near_start = self.tilt_of(self.mirror);
                    self.near_probes.clear();
                    self.near_gain = None;
                    self.near_last = None;
                    self.near_seen = None;
                    return self.act(measure(2 * self.mirror));
                }
                // Speckle or a clipped spot: its centroid points the way; step part-way.
                let damping = if s.localised && !s.clipped { 1.0 } else { 0.6 };
                let model = Affine {
                    offset: s.centre,
                    gain,
                };
                let delta = model.solve(centre).unwrap_or([0.0; 2]).map(|d| d * damping);
                self.far_last = Some((s.centre, delta));
                let u = self.tilt_of(self.mirror);
                self.tilt_to([u[0] + delta[0], u[1] + delta[1]])
            }
        }
    }

    /// At the near station: search while the spot has never shown; once it shows, probe
    /// each axis once (clipped centroids give the direction, the lever arm a floor on the
    /// size), then Newton steps to the centre refined by Broyden updates on clean spots.
    /// When the spot is centred and clean, predict the far response and go there.
    fn near_phase(
        &mut self,
        spot: Option<BeamSpot>,
        centre: Vec2,
        near_station: usize,
    ) -> RelayAction {
        let u = self.tilt_of(self.mirror);
        let Some(s) = spot else {
            self.near_last = None;
            if let Some(seen) = self.near_seen {
                // Lost after a move: go back half-way.
                return self.tilt_to([(u[0] + seen[0]) / 2.0, (u[1] + seen[1]) / 2.0]);
            }
            self.near.add_missing(u);
            let probe = self.near.next_probe(self.near_start);
            return self.tilt_to(probe);
        };
        self.near_seen = Some(u);
        let clean = s.localised && !s.clipped;
        let Some(gain) = self.near_gain else {
            self.near_probes.push((u, s.centre, clean));
            let base = self.near_probes[0].0;
            let bound = f64::from(self.limits.max_cumulative);
            let along = |axis: usize| {
                let mut t = base;
                t[axis] += if base[axis] + NEAR_PROBE <= bound {
                    NEAR_PROBE
                } else {
                    -NEAR_PROBE
                };
                t
            };
            if self.near_probes.len() < 3 {
                return self.tilt_to(along(self.near_probes.len() - 1));
            }
            let floor = PX_PER_STEP_MM * STATION_MM[near_station];
            let (u0, p0, c0) = self.near_probes[0];
            let mut gain = [[0.0; 2]; 2];
            for axis in [0, 1] {
                let (ua, pa, ca) = self.near_probes[axis + 1];
                let du = ua[axis] - u0[axis];
                let col = [(pa[0] - p0[0]) / du, (pa[1] - p0[1]) / du];
                if c0 && ca {
                    gain[0][axis] = col[0];
                    gain[1][axis] = col[1];
                } else {
                    // A clipped centroid shifts unreliably: take the sign along the image axis
                    // this tilt axis mainly drives (vertical tilt moves y, horizontal x), the
                    // size from the lever arm.
                    let row = 1 - axis;
                    gain[row][axis] = floor.max(col[row].abs()).copysign(col[row]);
                }
            }
            self.near_gain = Some(gain);
            return self.near_step(gain, s.centre, centre);
        };
        let gain = if clean {
            broyden(gain, self.near_last, s.centre)
        } else {
            flip_wrong_signs(gain, self.near_last, s.centre)
        };
        self.near_gain = Some(gain);
        if clean && distance(s.centre, centre) < CENTRED_PX {
            let ratio = STATION_MM[near_station + 1] / STATION_MM[near_station];
            self.far_gain = Some(gain.map(|row| row.map(|g| g * ratio)));
            self.far_last = None;
            self.far_dark = 0;
            self.phase = Phase::Far;
            return self.act(measure(near_station + 1));
        }
        self.near_step(gain, s.centre, centre)
    }

    /// A Newton step at the near station from the spot at `from` to `centre`.
    fn near_step(&mut self, gain: [[f64; 2]; 2], from: Vec2, centre: Vec2) -> RelayAction {
        let model = Affine { offset: from, gain };
        let delta = model.solve(centre).unwrap_or([0.0; 2]);
        let size = delta[0].hypot(delta[1]);
        let delta = delta.map(|d| d * (NEAR_REACH / size.max(1.0)).min(1.0));
        self.near_last = Some((from, delta));
        let u = self.tilt_of(self.mirror);
        self.tilt_to([u[0] + delta[0], u[1] + delta[1]])
    }

    /// Far station dark: back to the near station once, then a small search around.
    fn far_lost(&mut self, gain: [[f64; 2]; 2], centre: Vec2) -> RelayAction {
        self.far_dark += 1;
        self.far_last = None;
        if self.far_dark == 1 {
            self.phase = Phase::Near;
            return self.act(measure(2 * self.mirror));
        }
        let ring = [[1.0, 0.0], [-1.0, 0.0], [0.0, 1.0], [0.0, -1.0]];
        let d = ring[(self.far_dark - 2) % 4];
        let reach = 200.0 * (1 + (self.far_dark - 2) / 4) as f64;
        let model = Affine {
            offset: centre,
            gain,
        };
        let step = model
            .solve([centre[0] + d[0] * reach, centre[1] + d[1] * reach])
            .unwrap_or([0.0; 2]);
        let u = self.tilt_of(self.mirror);
        self.tilt_to([u[0] + step[0], u[1] + step[1]])
    }

    /// Tilts the current mirror to cumulative `target` (vertical, horizontal), within bounds.
    fn tilt_to(&mut self, target: Vec2) -> RelayAction {
        let m = self.mirror;
        let step = f64::from(self.limits.max_step);
        let bound = f64::from(self.limits.max_cumulative);
        let u = self.tilt_of(m);
        let delta = |a: usize| {
            let t = target[a].clamp(-bound, bound);
            (t - u[a]).clamp(-step, step).round() as i32
        };
        self.act(RelayAction::Tilt {
            mirror: m as u8,
            vertical: delta(0),
            horizontal: delta(1),
        })
    }

    fn act(&mut self, action: RelayAction) -> RelayAction {
        self.last = Some(action.clone());
        action
    }

    /// Books the last action, now that it was executed.
    fn apply_last(&mut self) {
        match self.last.take() {
            Some(RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            }) => {
                self.cumulative[2 * usize::from(mirror)] += vertical;
                self.cumulative[2 * usize::from(mirror) + 1] += horizontal;
            }
            Some(RelayAction::Measure { station }) => self.station = station.index(),
            _ => {}
        }
    }
}

fn new_tracker(limits: &RelayLimits) -> Tracker {
    let bound = f64::from(limits.max_cumulative);
    Tracker::new(PROBE, [[-bound, bound], [-bound, bound]])
}

fn measure(station: usize) -> RelayAction {
    RelayAction::Measure {
        station: Station::from_index(station).unwrap_or(Station::C8),
    }
}

/// The strongest region, if any.
fn best_spot(frame: &Frame) -> Option<BeamSpot> {
    find_beams(frame).into_iter().next()
}

/// Updates a response from the last tilt `last` (spot before, tilt) and the spot it produced.
fn broyden(gain: [[f64; 2]; 2], last: Option<(Vec2, Vec2)>, now: Vec2) -> [[f64; 2]; 2] {
    let Some((before, du)) = last else {
        return gain;
    };
    let norm = du[0] * du[0] + du[1] * du[1];
    if norm < 1.0 {
        return gain;
    }
    let dp = [now[0] - before[0], now[1] - before[1]];
    let mut out = gain;
    for (r, row) in out.iter_mut().enumerate() {
        let miss = dp[r] - (gain[r][0] * du[0] + gain[r][1] * du[1]);
        row[0] += miss * du[0] / norm;
        row[1] += miss * du[1] / norm;
    }
    out
}

/// For a clipped or speckled spot, flips a tilt axis's response when the image axis it
/// mainly drives (vertical tilt y, horizontal x) moved clearly against the prediction: a
/// clipped probe can give the wrong sign.
fn flip_wrong_signs(gain: [[f64; 2]; 2], last: Option<(Vec2, Vec2)>, now: Vec2) -> [[f64; 2]; 2] {
    let Some((before, du)) = last else {
        return gain;
    };
    let mut out = gain;
    for axis in [0, 1] {
        let row = 1 - axis;
        let predicted = gain[row][0] * du[0] + gain[row][1] * du[1];
        let observed = now[row] - before[row];
        if observed.abs() > 5.0 && predicted * observed < 0.0 {
            out[0][axis] = -gain[0][axis];
            out[1][axis] = -gain[1][axis];
        }
    }
    out
}
