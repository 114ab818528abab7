//! The score of one rig state, per task, and the scalar views of it used in traces and by
//! the baselines' privileged objective.

use serde::{Deserialize, Serialize};

use crate::task::cavity::CavityScore;
use crate::task::michelson::MichelsonScore;

/// The objective the paper gives BO when no beam reaches C8.
pub const RELAY_DARK_OBJECTIVE: f64 = -1e6;

/// The relay's per-state scoring data.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct RelayStateScore {
    /// Mirror m counts as aligned: beam clean through mirrors 0..=m and centred at its far
    /// station.
    pub aligned: [bool; 4],
    pub through_all_mirrors: bool,
    /// Beam centre at C8, px from the image centre, when light reaches the C8 sensor.
    pub c8_offset_px: Option<[f64; 2]>,
    /// Where the camera is now and the beam centre on its sensor, px from the image centre
    /// (at the station's calibrated pose), when light reaches it: for analysis next to the
    /// agent's claims. Unknown on a bench.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraView>,
}

/// The camera's station and the beam's true place on it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraView {
    pub station: optalign_optics::Station,
    pub offset_px: Option<[f64; 2]>,
}

/// A scored state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "task", rename_all = "snake_case")]
pub enum Score {
    Michelson(MichelsonScore),
    Cavity(CavityScore),
    Relay(RelayStateScore),
}

impl Score {
    /// The task's error: Michelson px, cavity motor steps, relay px from the C8 centre
    /// (`None` while no light reaches C8).
    pub fn error(&self) -> Option<f64> {
        match self {
            Self::Michelson(score) => Some(score.error_px),
            Self::Cavity(score) => Some(score.error_steps),
            Self::Relay(score) => score.c8_offset_px.map(|[x, y]| x.hypot(y)),
        }
    }

    /// The privileged scalar objective (to maximise) that the paper gives BO: minus the
    /// error, and for the relay -1e6 whenever no beam reaches C8.
    pub fn objective(&self) -> f64 {
        self.error().map_or(RELAY_DARK_OBJECTIVE, |error| -error)
    }
}
