//! The simulated rig: a scene rendered from the true shaft positions of simulated mounts
//! driven by the simulated firmware, and for the relay a simulated camera mover that places
//! the camera with a small random error at each station. Frames can be asked for at a
//! smaller size (reinforcement learning wants small observations): the Michelson renders
//! straight onto a binned camera when its scene allows, everything else is area-averaged.

use async_trait::async_trait;
use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{CameraPose, Cavity, Frame, Michelson, Relay, Station};
use optalign_protocol::AxisValue;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::controllers::ControllerView;
use super::downsample::area_average;
use super::motors::{MotorPath, SimMotors};
use super::score::{CameraView, RelayStateScore, Score};
use super::{Executed, Rig};
use crate::scenario::{ScenarioFile, TimingParams};
use crate::task::cavity::CavityScore;
use crate::task::michelson::MichelsonScore;
use crate::task::relay::{RelayAction, aligned_mirrors, axis_of};
use crate::task::{Action, TaskKind};

enum Scene {
    /// The scene, and the same scene on a binned camera when frames are asked for smaller.
    Michelson(Michelson, Option<Box<Michelson>>),
    Cavity(Cavity),
    Relay {
        relay: Box<Relay>,
        pose: CameraPose,
        placements: Box<ChaCha8Rng>,
    },
}

/// A simulated bench for one task and one seed.
pub struct SimRig {
    task: TaskKind,
    scene: Scene,
    motors: SimMotors,
    /// The absolute settings last commanded (Michelson, cavity), for the commanded score.
    commanded: Vec<i32>,
    frames: u64,
    timing: TimingParams,
    centred_tolerance_px: f64,
    /// The size frames are delivered at, when smaller than the scene's camera.
    frame_size: Option<[u32; 2]>,
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
        Self::check_frame_size(task, scenario, frame_size)?;
        let camera = scenario.geometry(task).image_px.unwrap_or_default();
        let frame_size = frame_size.filter(|&size| size != camera);
        let scene = match task {
            TaskKind::Michelson => {
                let offsets = michelson_offsets(&scenario.michelson, seed);
                let binned = frame_size
                    .and_then(|[width, height]| scenario.michelson.binned(width, height))
                    .map(|params| Michelson::new(params, offsets).map(Box::new))
                    .transpose()?;
                Scene::Michelson(Michelson::new(scenario.michelson.clone(), offsets)?, binned)
            }
            TaskKind::Cavity => {
                let offsets = cavity_offsets(&scenario.cavity, seed);
                Scene::Cavity(Cavity::new(scenario.cavity.clone(), offsets)?)
            }
            TaskKind::Relay => {
                let offsets = relay_offsets(&scenario.relay, seed)?;
                let relay = Box::new(Relay::new(scenario.relay.clone(), offsets)?);
                let mut placements = Box::new(ChaCha8Rng::seed_from_u64(seed ^ 0x0c8a_11e7));
                let pose = CameraPose::place(Station::C8, &scenario.relay.camera, &mut placements);
                Scene::Relay {
                    relay,
                    pose,
                    placements,
                }
            }
        };
        let motors = SimMotors::start(path, task.axes(), &scenario.mount, seed).await?;
        Ok(Self {
            task,
            scene,
            motors,
            commanded: vec![0; task.axes()],
            frames: 0,
            timing: scenario.timing.clone(),
            centred_tolerance_px: scenario.tasks.relay.centred_tolerance_px,
            frame_size,
        })
    }

    /// Checks that frames of `frame_size` (width, height) can be had from `task`'s camera:
    /// each side from 1 up to the camera's.
    pub fn check_frame_size(
        task: TaskKind,
        scenario: &ScenarioFile,
        frame_size: Option<[u32; 2]>,
    ) -> anyhow::Result<()> {
        let camera = scenario.geometry(task).image_px.unwrap_or_default();
        if let Some([width, height]) = frame_size {
            anyhow::ensure!(
                (1..=camera[0]).contains(&width) && (1..=camera[1]).contains(&height),
                "a frame size of ({width}, {height}) does not fit the {task} camera of {}x{}: each side must be 1 up to the camera's",
                camera[0],
                camera[1]
            );
        }
        Ok(())
    }

    fn render(&mut self) -> anyhow::Result<Frame> {
        let shafts = self.motors.shafts();
        let index = self.frames;
        self.frames += 1;
        let frame = match &self.scene {
            Scene::Michelson(_, Some(binned)) => return Ok(binned.render(&shafts, index)),
            Scene::Michelson(scene, None) => scene.render(&shafts, index),
            Scene::Cavity(scene) => scene.render(&shafts, index),
            Scene::Relay { relay, pose, .. } => relay.render(&shafts, pose, index),
        };
        match self.frame_size {
            Some([width, height]) => area_average(&frame, width, height),
            None => Ok(frame),
        }
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
        self.task
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
                let Scene::Relay {
                    relay,
                    pose,
                    placements,
                } = &mut self.scene
                else {
                    anyhow::bail!("a relay action reached a {} rig", self.task);
                };
                let moved = pose.station != *station;
                *pose = CameraPose::place(*station, &relay.params().camera, placements.as_mut());
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
        let shafts = self.motors.shafts();
        match &self.scene {
            Scene::Michelson(scene, _) => {
                let truth = scene.truth(&shafts);
                Score::Michelson(MichelsonScore {
                    error_px: truth.error_px,
                    commanded_error_px: scene.truth(&self.commanded).error_px,
                    beam_centres_px: truth.beam_centres_px,
                })
            }
            Scene::Cavity(scene) => {
                let truth = scene.truth(&shafts);
                Score::Cavity(CavityScore {
                    error_steps: truth.error_steps,
                    success: truth.success,
                    secondary_centre_px: Some(truth.secondary_centre_px),
                })
            }
            Scene::Relay { relay, pose, .. } => {
                let truth = relay.truth(&shafts);
                let seen = &truth.stations[pose.station.index()];
                Score::Relay(RelayStateScore {
                    aligned: aligned_mirrors(&truth, self.centred_tolerance_px),
                    through_all_mirrors: truth.mirrors.iter().all(|m| m.reached() && !m.clipped()),
                    c8_offset_px: truth.stations[Station::C8.index()]
                        .lit
                        .then_some(truth.c8_offset_px)
                        .flatten(),
                    camera: Some(CameraView {
                        station: pose.station,
                        offset_px: seen.lit.then_some(seen.offset_px).flatten(),
                    }),
                })
            }
        }
    }
}
