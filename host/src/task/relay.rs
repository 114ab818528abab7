//! The relay task: relative tilts of four two-axis mirrors with per-action and cumulative
//! bounds, camera moves between eight stations, done only at C8; scored by per-mirror
//! milestones, the beam getting through all four mirrors and a centred spot at C8.

use optalign_optics::{RelayTruth, Station};
use serde::{Deserialize, Serialize};

use super::check_budget;

/// Axis of mirror `m`'s vertical tilt is `2m`, of its horizontal tilt `2m + 1`.
pub fn axis_of(mirror: u8, horizontal: bool) -> usize {
    usize::from(mirror) * 2 + usize::from(horizontal)
}

/// `M2 vertical` for axis 2, and so on.
pub fn axis_label(axis: usize) -> String {
    format!(
        "M{} {}",
        axis / 2 + 1,
        if axis.is_multiple_of(2) {
            "vertical"
        } else {
            "horizontal"
        }
    )
}

/// One relay action.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "action", rename_all = "snake_case")]
pub enum RelayAction {
    /// Relative tilt of one mirror (0 = M1 .. 3 = M4), in motor steps.
    Tilt {
        mirror: u8,
        vertical: i32,
        horizontal: i32,
    },
    /// Relative tilts of all eight axes at once (axis order as in [`axis_of`]); the
    /// numerical baselines search whole configurations this way.
    TiltAll { deltas: [i32; 8] },
    /// Move the camera to a station (or take another image if already there).
    Measure { station: Station },
    /// Declare the relay aligned (accepted only at C8).
    Done,
}

impl RelayAction {
    pub fn describe(&self) -> String {
        match self {
            Self::Tilt {
                mirror,
                vertical,
                horizontal,
            } => {
                format!(
                    "tilt M{} vertical {vertical:+} horizontal {horizontal:+}",
                    mirror + 1
                )
            }
            Self::TiltAll { deltas } => format!("tilt all {deltas:?}"),
            Self::Measure { station } => format!("measure at {station}"),
            Self::Done => "done".into(),
        }
    }
}

/// Bounds, budget and scoring tolerance (`[tasks.relay]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelayLimits {
    /// Evaluations per run. Default 100.
    pub budget: usize,
    /// Largest relative tilt per axis in one action, steps. Default 15000.
    pub max_step: i32,
    /// Bound on the cumulative commanded steps per axis, counted from commands. Default 30000.
    pub max_cumulative: i32,
    /// A beam counts as centred at a station when its centre is within this many pixels of
    /// the image centre. Default 50 (0.5 mm on the default 10 µm-pixel camera).
    pub centred_tolerance_px: f64,
}

impl Default for RelayLimits {
    fn default() -> Self {
        Self {
            budget: 100,
            max_step: 15_000,
            max_cumulative: 30_000,
            centred_tolerance_px: 50.0,
        }
    }
}

impl RelayLimits {
    pub fn validate(&self) -> Result<(), String> {
        check_budget("tasks.relay.budget", self.budget)?;
        if self.max_step <= 0 {
            return Err(format!(
                "tasks.relay.max_step: must be > 0, got {}",
                self.max_step
            ));
        }
        if self.max_cumulative < self.max_step {
            return Err(format!(
                "tasks.relay.max_cumulative: must be >= max_step ({}), got {}",
                self.max_step, self.max_cumulative
            ));
        }
        if self.centred_tolerance_px.is_nan() || self.centred_tolerance_px <= 0.0 {
            return Err(format!(
                "tasks.relay.centred_tolerance_px: must be > 0, got {}",
                self.centred_tolerance_px
            ));
        }
        Ok(())
    }
}

/// The relay's bookkeeping: cumulative commands per axis and where the camera is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelayState {
    pub cumulative: [i32; 8],
    pub station: Station,
}

impl Default for RelayState {
    fn default() -> Self {
        Self {
            cumulative: [0; 8],
            station: Station::C8,
        }
    }
}

impl RelayState {
    /// Checks an action against the bounds and the camera position.
    pub fn check(&self, limits: &RelayLimits, action: &RelayAction) -> Result<(), String> {
        match action {
            RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            } => {
                if *mirror > 3 {
                    return Err(format!(
                        "rejected: mirror must be M1..M4, got index {mirror}"
                    ));
                }
                let mut problems = Vec::new();
                for (name, delta, horizontal_axis) in [
                    ("vertical", *vertical, false),
                    ("horizontal", *horizontal, true),
                ] {
                    let total = self.cumulative[axis_of(*mirror, horizontal_axis)];
                    let low = (-limits.max_cumulative - total).max(-limits.max_step);
                    let high = (limits.max_cumulative - total).min(limits.max_step);
                    if !(low..=high).contains(&delta) {
                        problems.push(format!(
                            "M{} {name} {delta:+} is not allowed (per action within [-{}, {}], cumulative {total:+} must stay within [-{}, {}]); allowed now: [{low}, {high}]",
                            mirror + 1,
                            limits.max_step,
                            limits.max_step,
                            limits.max_cumulative,
                            limits.max_cumulative,
                        ));
                    }
                }
                if problems.is_empty() {
                    Ok(())
                } else {
                    Err(format!("rejected, nothing moved: {}", problems.join("; ")))
                }
            }
            RelayAction::TiltAll { deltas } => {
                let problems: Vec<String> = deltas
                    .iter()
                    .enumerate()
                    .filter_map(|(axis, &delta)| {
                        let (low, high) = self.allowed(limits, axis);
                        (!(low..=high).contains(&delta)).then(|| {
                            format!(
                                "axis {axis} ({}) {delta:+}: allowed now [{low}, {high}]",
                                axis_label(axis)
                            )
                        })
                    })
                    .collect();
                if problems.is_empty() {
                    Ok(())
                } else {
                    Err(format!("rejected, nothing moved: {}", problems.join("; ")))
                }
            }
            RelayAction::Measure { .. } => Ok(()),
            RelayAction::Done if self.station == Station::C8 => Ok(()),
            RelayAction::Done => Err(format!(
                "rejected: done is accepted only while the camera is at C8; it is at {}",
                self.station
            )),
        }
    }

    /// The relative tilt allowed on `axis` now: per-action and cumulative bounds combined.
    pub fn allowed(&self, limits: &RelayLimits, axis: usize) -> (i32, i32) {
        let total = self.cumulative[axis];
        let low = (-limits.max_cumulative - total).max(-limits.max_step);
        let high = (limits.max_cumulative - total).min(limits.max_step);
        (low, high)
    }

    /// Records an accepted action.
    pub fn apply(&mut self, action: &RelayAction) {
        match action {
            RelayAction::TiltAll { deltas } => {
                for (total, delta) in self.cumulative.iter_mut().zip(deltas) {
                    *total += delta;
                }
            }
            RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            } => {
                self.cumulative[axis_of(*mirror, false)] += vertical;
                self.cumulative[axis_of(*mirror, true)] += horizontal;
            }
            RelayAction::Measure { station } => self.station = *station,
            RelayAction::Done => {}
        }
    }
}

/// The far station of each mirror's outgoing segment: C2, C4, C6, C8.
pub const FAR_STATIONS: [Station; 4] = [Station::C2, Station::C4, Station::C6, Station::C8];

/// Per-mirror alignment in one state: the beam reaches and leaves mirrors 0..=m unclipped
/// and is centred at mirror m's far station.
pub fn aligned_mirrors(truth: &RelayTruth, tolerance_px: f64) -> [bool; 4] {
    let mut aligned = [false; 4];
    let mut clean_so_far = true;
    for (m, far) in FAR_STATIONS.iter().enumerate() {
        let mirror = &truth.mirrors[m];
        clean_so_far &= mirror.reached() && !mirror.clipped();
        let station = &truth.stations[far.index()];
        let centred = station.lit
            && station
                .offset_px
                .is_some_and(|[x, y]| x.hypot(y) <= tolerance_px);
        aligned[m] = clean_so_far && centred;
    }
    aligned
}

/// Milestones from the per-evaluation alignment flags (index 0 = the initial state): the
/// evaluation from which each mirror stayed aligned to the end, or `None` when it was not
/// aligned at the end.
pub fn milestones(history: &[[bool; 4]]) -> [Option<usize>; 4] {
    std::array::from_fn(|m| {
        let stays_from = history
            .iter()
            .rposition(|flags| !flags[m])
            .map_or(0, |last_bad| last_bad + 1);
        (stays_from < history.len()).then_some(stays_from)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cumulative_bounds_reject_with_the_allowed_range() {
        let limits = RelayLimits::default();
        let mut state = RelayState::default();
        let tilt = RelayAction::Tilt {
            mirror: 1,
            vertical: 15_000,
            horizontal: 0,
        };
        state.check(&limits, &tilt).unwrap();
        state.apply(&tilt);
        state.apply(&tilt);
        let error = state
            .check(
                &limits,
                &RelayAction::Tilt {
                    mirror: 1,
                    vertical: 1,
                    horizontal: 0,
                },
            )
            .unwrap_err();
        assert!(error.contains("allowed now: [-15000, 0]"), "{error}");
        let error = state
            .check(
                &limits,
                &RelayAction::Tilt {
                    mirror: 0,
                    vertical: 0,
                    horizontal: 15_001,
                },
            )
            .unwrap_err();
        assert!(error.contains("M1 horizontal +15001"), "{error}");
    }

    #[test]
    fn done_only_at_c8() {
        let limits = RelayLimits::default();
        let mut state = RelayState::default();
        assert!(state.check(&limits, &RelayAction::Done).is_ok());
        state.apply(&RelayAction::Measure {
            station: Station::C3,
        });
        assert!(
            state
                .check(&limits, &RelayAction::Done)
                .unwrap_err()
                .contains("at C3")
        );
    }

    #[test]
    fn milestones_count_from_when_alignment_stays() {
        let t = true;
        let f = false;
        let history = [
            [f, f, f, f],
            [t, f, f, f],
            [f, f, f, f],
            [t, f, f, f],
            [t, t, f, f],
            [t, t, f, f],
        ];
        assert_eq!(milestones(&history), [Some(3), Some(4), None, None]);
        assert_eq!(milestones(&[[t, t, t, t]]), [Some(0); 4]);
    }
}
