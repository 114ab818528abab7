//! The simulated rig: a [`SimCamera`] watching simulated mounts driven by the simulated
//! firmware ([`SimMotors`]), and for the relay a simulated camera mover that places the
//! camera with a small random error at each station.

use async_trait::async_trait;
use optalign_optics::Frame;
use optalign_protocol::AxisValue;

use super::controllers::ControllerView;
use super::motors::{MotorPath, SimMotors};
use super::score::Score;
use super::sim_camera::SimCamera;
use super::{Executed, Rig};
use crate::scenario::{ScenarioFile, TimingParams};
use crate::task::relay::{RelayAction, axis_of};
use crate::task::{Action, TaskKind};

/// A simulated bench for one task and one seed.
pub struct SimRig {
    camera: SimCamera,
    motors: SimMotors,
    /// The absolute settings last commanded (Michelson, cavity), for the commanded score.
    commanded: Vec<i32>,
    timing: TimingParams,
}

impl SimRig {
    /// Builds the scene for `seed` (hidden offsets drawn from the scenario) and starts its
    /// simulated controller on the chosen motor path.
    pub async fn new(
        task: TaskKind,
        scenario: &ScenarioFile,
        seed: u64,
        path: MotorPath,
    ) -> anyhow::Result<Self> {
        Self::with_frame_size(task, scenario, seed, path, None).await
    }

    /// Like [`Self::new`], with frames delivered at `frame_size` (width, height), each side
    /// at most the scene camera's.
    pub async fn with_frame_size(
        task: TaskKind,
        scenario: &ScenarioFile,
        seed: u64,
        path: MotorPath,
        frame_size: Option<[u32; 2]>,
    ) -> anyhow::Result<Self> {
        let camera = SimCamera::new(task, scenario, seed, frame_size)?;
        let motors = SimMotors::start(path, task.axes(), &scenario.mount, seed).await?;
        Ok(Self {
            camera,
            motors,
            commanded: vec![0; task.axes()],
            timing: scenario.timing.clone(),
        })
    }

    fn render(&mut self) -> anyhow::Result<Frame> {
        let shafts = self.motors.shafts();
        self.camera.render(&shafts)
    }

    /// True shaft positions (hidden truth; for tests and scoring).
    pub fn shafts(&self) -> Vec<i32> {
        self.motors.shafts()
    }

    /// Relative moves of (axis, delta) pairs; zero deltas are skipped. Returns the travel
    /// and settling time, s.
    async fn move_relative(&mut self, deltas: &[(usize, i32)]) -> anyhow::Result<f64> {
        let deltas: Vec<AxisValue> = deltas
            .iter()
            .filter(|(_, delta)| *delta != 0)
            .map(|&(axis, steps)| AxisValue {
                axis: axis as u8,
                steps,
            })
            .collect();
        if deltas.is_empty() {
            return Ok(0.0);
        }
        Ok(self.motors.travel(&deltas, true).await? + self.timing.settle_after_move_s)
    }

    async fn move_absolute(&mut self, command: &[i32]) -> anyhow::Result<f64> {
        let targets: Vec<AxisValue> = command
            .iter()
            .enumerate()
            .filter(|(axis, value)| self.commanded[*axis] != **value)
            .map(|(axis, &steps)| AxisValue {
                axis: axis as u8,
                steps,
            })
            .collect();
        if targets.is_empty() {
            return Ok(0.0);
        }
        let seconds = self.motors.travel(&targets, false).await?;
        self.commanded = command.to_vec();
        Ok(seconds + self.timing.settle_after_move_s)
    }
}

#[async_trait]
impl Rig for SimRig {
    fn task(&self) -> TaskKind {
        self.camera.task()
    }

    async fn initial_image(&mut self) -> anyhow::Result<Frame> {
        self.render()
    }

    async fn execute(&mut self, action: &Action) -> anyhow::Result<Executed> {
        let (motor_time_s, camera_move_s) = match action {
            Action::Michelson { command, .. } => (self.move_absolute(command).await?, 0.0),
            Action::Cavity { command, .. } => (self.move_absolute(command).await?, 0.0),
            Action::Relay(RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            }) => {
                let deltas = [
                    (axis_of(*mirror, false), *vertical),
                    (axis_of(*mirror, true), *horizontal),
                ];
                (self.move_relative(&deltas).await?, 0.0)
            }
            Action::Relay(RelayAction::TiltAll { deltas }) => {
                let deltas: Vec<(usize, i32)> = deltas.iter().copied().enumerate().collect();
                (self.move_relative(&deltas).await?, 0.0)
            }
            Action::Relay(RelayAction::Measure { station }) => {
                let moved = self.camera.place(*station)?;
                (
                    0.0,
                    if moved {
                        self.timing.camera_move_s
                    } else {
                        0.0
                    },
                )
            }
            Action::Relay(RelayAction::Done) => (0.0, 0.0),
        };
        Ok(Executed {
            image: self.render()?,
            motor_time_s,
            camera_time_s: camera_move_s + self.timing.frame_s,
        })
    }

    async fn emergency_stop(&mut self) -> anyhow::Result<()> {
        self.motors.emergency_stop().await
    }

    async fn controllers(&mut self) -> anyhow::Result<Vec<ControllerView>> {
        let status = self.motors.status().await?;
        Ok(vec![ControllerView::from_status("simulated", &status)])
    }

    fn score(&self) -> Score {
        self.camera.score(&self.motors.shafts(), &self.commanded)
    }
}
