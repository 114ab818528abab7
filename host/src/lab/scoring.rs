//! Scoring on a bench, where there is no hidden truth: Michelson from the commanded
//! positions through the response calibration (as the paper does), the cavity from the
//! recorded aligned reference, the relay from what the camera saw at each far station
//! after the last adjustment of the mirrors upstream of it.

use anyhow::Context;
use optalign_optics::{Frame, Station};

use super::calibration::ResponseCalibration;
use super::rigfile::RigFile;
use crate::imaging::{Picture, find_beams};
use crate::rig::{RelayStateScore, Score};
use crate::task::TaskKind;
use crate::task::cavity::CavityScore;
use crate::task::michelson::MichelsonScore;
use crate::task::relay::FAR_STATIONS;

/// What the camera last showed at a station: the localised spot's offset from the image
/// centre, or `None` for no localised spot (dark or speckle).
type StationView = Option<[f64; 2]>;

/// What a bench run's error is, for a reader: its unit, what it was measured from, and
/// what "aligned" means on this bench.
#[derive(Clone, Debug, PartialEq)]
pub struct ErrorBasis {
    pub unit: &'static str,
    pub measured_from: String,
    pub aligned_when: String,
}

/// The basis of `rig`'s score (as `LabScorer` computes it).
pub fn error_basis(rig: &RigFile) -> ErrorBasis {
    match rig.task {
        TaskKind::Michelson => {
            let path = rig
                .scoring
                .michelson_calibration
                .as_ref()
                .map_or("(none named)".into(), |p| p.display().to_string());
            let residuals = rig
                .scoring
                .michelson_calibration
                .as_ref()
                .and_then(|p| ResponseCalibration::load(p).ok())
                .map(|c| {
                    let r: Vec<String> = c
                        .mirrors
                        .iter()
                        .map(|m| format!("{:.2}", m.residual_rms_px))
                        .collect();
                    format!(", fit residuals {} px RMS", r.join(" and "))
                })
                .unwrap_or_default();
            ErrorBasis {
                unit: "px",
                measured_from: format!(
                    "the two beams' distances from the image centre, summed, predicted from the commanded motor positions through the response calibration {path}{residuals}"
                ),
                aligned_when: format!(
                    "both beam centres within {} px (summed) of the camera's centre, where they overlap and fringes appear",
                    rig.limits.michelson.success_error_px
                ),
            }
        }
        TaskKind::Cavity => ErrorBasis {
            unit: "motor steps",
            measured_from: match rig.scoring.cavity_aligned {
                Some([x, y]) => format!(
                    "the in-coupler's distance from its hand-aligned controller positions x = {x}, y = {y} (scoring.cavity_aligned)"
                ),
                None => "the in-coupler's distance from its hand-aligned positions (none recorded)".into(),
            },
            aligned_when: format!(
                "the in-coupler within {CAVITY_SUCCESS_STEPS} steps of the hand-aligned positions, where the secondary beam lies on the primary"
            ),
        },
        TaskKind::Relay => ErrorBasis {
            unit: "px",
            measured_from: "the localised spot's offset from the image centre at C8, as the camera saw it after the last adjustment".into(),
            aligned_when: format!(
                "the beam passes all four mirrors and a localised spot is within {} px of the image centre at C8",
                rig.limits.relay.centred_tolerance_px
            ),
        },
    }
}

/// A cavity counts as aligned within this many steps of its reference (the paper's rule).
pub(crate) const CAVITY_SUCCESS_STEPS: f64 = 500.0;

pub struct LabScorer {
    task: TaskKind,
    calibration: Option<ResponseCalibration>,
    cavity_aligned: Option<[i32; 2]>,
    cavity_success_steps: f64,
    tolerance_px: f64,
    /// Relay: latest view per station, cleared when a mirror upstream of it moves.
    views: [Option<StationView>; 8],
}

impl LabScorer {
    /// Checks the rig file says how its task is scored, and that the files it names hold
    /// what scoring needs.
    pub fn check(rig: &RigFile) -> anyhow::Result<()> {
        match rig.task {
            TaskKind::Michelson => {
                let path = rig.scoring.michelson_calibration.as_ref().context(
                    "scoring.michelson_calibration: a Michelson bench is scored through its response calibration; run `optalign calibrate response --rig FILE --mirror 1` and `--mirror 2` and name the file here",
                )?;
                let calibration = ResponseCalibration::load(path)?;
                for mirror in [1, 2] {
                    calibration
                        .mirror(mirror)
                        .with_context(|| format!("{}: no entry for mirror {mirror}; run `optalign calibrate response --mirror {mirror}`", path.display()))?;
                }
            }
            TaskKind::Cavity => {
                rig.scoring.cavity_aligned.context(
                    "scoring.cavity_aligned: a cavity bench is scored against the aligned reference; align it once by hand and record the controller positions of x and y here",
                )?;
            }
            TaskKind::Relay => {}
        }
        Ok(())
    }

    /// A scorer for the bench; scoring a task whose data is missing gives an infinite error
    /// (use [`check`](Self::check) first, as runs do).
    pub fn new(rig: &RigFile) -> Self {
        let calibration = rig
            .scoring
            .michelson_calibration
            .as_ref()
            .and_then(|path| ResponseCalibration::load(path).ok());
        Self {
            task: rig.task,
            calibration,
            cavity_aligned: rig.scoring.cavity_aligned,
            cavity_success_steps: CAVITY_SUCCESS_STEPS,
            tolerance_px: rig.limits.relay.centred_tolerance_px,
            views: [None; 8],
        }
    }

    /// Records what the camera saw at `station` (relay).
    pub fn observe(&mut self, station: Station, frame: &Frame) {
        if self.task != TaskKind::Relay {
            return;
        }
        let centre = [
            f64::from(frame.width()) / 2.0,
            f64::from(frame.height()) / 2.0,
        ];
        let spot = find_beams(&Picture::new(frame))
            .into_iter()
            .find(|beam| beam.localised)
            .map(|beam| [beam.centre[0] - centre[0], beam.centre[1] - centre[1]]);
        self.views[station.index()] = Some(spot);
    }

    /// A mirror moved: every station downstream of it must be looked at again.
    pub fn adjusted(&mut self, mirror: usize) {
        for view in &mut self.views[2 * mirror..] {
            *view = None;
        }
    }

    /// Scores the state from task-axis positions and controller positions.
    pub fn score(&self, task_positions: &[f64], controller_positions: &[f64]) -> Score {
        match self.task {
            TaskKind::Michelson => {
                let unknown = [f64::INFINITY; 2];
                let centre = self
                    .calibration
                    .as_ref()
                    .map_or(unknown, |c| c.image_size_px.map(|s| f64::from(s) / 2.0));
                let beams = [1, 2].map(|m| {
                    self.calibration
                        .as_ref()
                        .and_then(|c| c.mirror(m))
                        .map_or(unknown, |r| r.predict(task_positions))
                });
                let error_px = beams
                    .iter()
                    .map(|b| (b[0] - centre[0]).hypot(b[1] - centre[1]))
                    .sum();
                Score::Michelson(MichelsonScore {
                    error_px,
                    commanded_error_px: error_px,
                    beam_centres_px: beams,
                })
            }
            TaskKind::Cavity => {
                let [x, y] = self
                    .cavity_aligned
                    .map_or([f64::INFINITY; 2], |r| r.map(f64::from));
                let error_steps = (controller_positions[0] - x).hypot(controller_positions[1] - y);
                Score::Cavity(CavityScore {
                    error_steps,
                    success: error_steps <= self.cavity_success_steps,
                    secondary_centre_px: None,
                })
            }
            TaskKind::Relay => {
                let centred = |station: Station| matches!(self.views[station.index()], Some(Some([x, y])) if x.hypot(y) <= self.tolerance_px);
                let mut aligned = [false; 4];
                let mut upstream = true;
                for (m, far) in FAR_STATIONS.iter().enumerate() {
                    upstream &= centred(*far);
                    aligned[m] = upstream;
                }
                let c8 = self.views[Station::C8.index()].flatten();
                Score::Relay(RelayStateScore {
                    aligned,
                    through_all_mirrors: c8.is_some(),
                    c8_offset_px: c8,
                    camera: None,
                })
            }
        }
    }
}
