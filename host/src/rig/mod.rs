//! Rigs: what a run talks to. A rig executes validated actions (motor moves, camera moves)
//! and returns the next camera image; it also scores its own state for the run's records.
//! [`SimRig`] drives a simulated scene through the simulated firmware; a lab rig drives a
//! real bench through the same trait, so every policy works unchanged on both.

mod controllers;
mod downsample;
mod motors;
mod score;
mod sim;
mod sim_camera;

use async_trait::async_trait;
use optalign_optics::Frame;

use crate::task::{Action, TaskKind};

pub use controllers::{AxisView, ControllerView, fault_names};
pub use motors::{MotorPath, SimMotors, rig_axis_config, rig_peer_options};
pub use score::{CameraView, RelayStateScore, Score};
pub use sim::SimRig;
pub use sim_camera::SimCamera;

/// What executing one action produced.
#[derive(Clone, Debug)]
pub struct Executed {
    pub image: Frame,
    /// Modelled time the motors travelled, s.
    pub motor_time_s: f64,
    /// Modelled time the camera took to move and settle, and the frame to be grabbed, s.
    pub camera_time_s: f64,
}

/// A bench, simulated or real, that a run drives.
#[async_trait]
pub trait Rig: Send {
    fn task(&self) -> TaskKind;

    /// The image before any action.
    async fn initial_image(&mut self) -> anyhow::Result<Frame>;

    /// Executes an action the task has already validated.
    async fn execute(&mut self, action: &Action) -> anyhow::Result<Executed>;

    /// Scores the current state. In simulation this reads the hidden truth; it is for the
    /// run's records (and the privileged objective of the baselines), never for a policy.
    fn score(&self) -> Score;

    /// Emergency stop on every controller of the rig: motion ends at once, the coils go
    /// off and each controller latches the stop until it is cleared.
    async fn emergency_stop(&mut self) -> anyhow::Result<()>;

    /// Each controller's state as it reports it (for the operator's view).
    async fn controllers(&mut self) -> anyhow::Result<Vec<ControllerView>>;
}
