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

/// Distance of each station from the mirror before it, mm: near stations 25 mm after their
/// mirror, far ones just before the next mirror (C8 well along the output).
const STATION_MM: [f64; 8] = [25.0, 254.4, 25.0, 178.2, 25.0, 254.4, 25.0, 300.0];

/// A spot this close to the image centre is centred, px.
const CENTRED_PX: f64 = 10.0;

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
                let u = self.tilt_of(self.mirror);
                match spot {
                    Some(s) if s.localised && !s.clipped => self.near.add_clean(u, s.centre),
                    Some(s) => self.near.add_partial(u, s.centre),
                    None => self.near.add_missing(u),
                }
                let Some(model) = self
                    .near
                    .model()
                    .filter(|m| m.worst_residual(&self.near.clean) < 8.0)
                else {
                    let probe = self.near.next_probe(self.near_start);
                    return self.tilt_to(probe);
                };
                let here = model.predict(u);
                if distance(here, centre) < CENTRED_PX
                    || spot.is_some_and(|s| distance(s.centre, centre) < CENTRED_PX)
                {
                    let ratio = STATION_MM[far_station] / STATION_MM[near_station];
                    self.far_gain = Some(model.gain.map(|row| row.map(|g| g * ratio)));
                    self.far_last = None;
                    self.far_dark = 0;
                    self.phase = Phase::Far;
                    return self.act(measure(far_station));
                }
                let aim = model.solve(centre).unwrap_or(u);
                self.tilt_to(aim)
            }
            Phase::Far => {
                if self.station != far_station {
                    return self.act(measure(far_station));
                }
                let gain = self.far_gain.unwrap_or([[1.0, 0.0], [0.0, 1.0]]);
                let Some(s) = spot else {
                    return self.far_lost(gain, centre);
                };
                let gain = self.broyden(gain, s.centre);
                self.far_gain = Some(gain);
                if s.localised && !s.clipped && distance(s.centre, centre) < CENTRED_PX {
                    if self.mirror == 3 {
                        return self.act(RelayAction::Done);
                    }
                    self.mirror += 1;
                    self.phase = Phase::Near;
                    self.near = new_tracker(&self.limits);
                    self.near_start = self.tilt_of(self.mirror);
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

    /// Updates the far response from the last tilt and the spot it produced.
    fn broyden(&self, gain: [[f64; 2]; 2], now: Vec2) -> [[f64; 2]; 2] {
        let Some((before, du)) = self.far_last else {
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
