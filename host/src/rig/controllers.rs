//! What an operator sees of a rig's controllers: per controller, whether the emergency
//! latch is set and, per axis, position, motion, coil power and faults, as the controller
//! itself reports them.

use optalign_protocol::{Faults, Status};
use serde::{Deserialize, Serialize};

/// One controller's reported state.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ControllerView {
    pub name: String,
    pub emergency_stopped: bool,
    pub axes: Vec<AxisView>,
}

/// One axis as its controller reports it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AxisView {
    pub axis: u8,
    pub position: i32,
    pub moving: bool,
    pub powered: bool,
    /// Names of the set fault bits (empty when clear).
    pub faults: Vec<String>,
}

impl ControllerView {
    /// The view of a controller's status reply.
    pub fn from_status(name: &str, status: &Status) -> Self {
        Self {
            name: name.to_owned(),
            emergency_stopped: status.emergency_stopped,
            axes: status
                .axes
                .iter()
                .enumerate()
                .map(|(axis, state)| AxisView {
                    axis: axis as u8,
                    position: state.position,
                    moving: state.moving,
                    powered: state.powered,
                    faults: fault_names(state.faults)
                        .into_iter()
                        .map(str::to_owned)
                        .collect(),
                })
                .collect(),
        }
    }
}

/// The names of the set fault bits.
pub fn fault_names(faults: Faults) -> Vec<&'static str> {
    [
        (Faults::EMERGENCY_STOP, "emergency-stop"),
        (Faults::DRIVER, "driver"),
        (Faults::POSITION_LOST, "position-lost"),
    ]
    .into_iter()
    .filter(|(bit, _)| faults.has(*bit))
    .map(|(_, name)| name)
    .collect()
}
