//! The simulated camera of a task and seed: the scene (hidden offsets drawn for the seed)
//! rendered from the true shaft positions it is handed, frame after frame (each frame's
//! noise drawn for its index), and for the relay the camera's placement at each station
//! with a small random error. Frames can be asked for at a smaller size: the Michelson
//! renders straight onto a binned camera when its scene allows, everything else is
//! area-averaged. [`super::SimRig`] watches its simulated mounts with it; the Python
//! package's simulated rig watches a simulated controller.

use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{CameraPose, Cavity, Frame, Michelson, Relay, Station};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::downsample::area_average;
use super::score::{CameraView, RelayStateScore, Score};
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;
use crate::task::cavity::CavityScore;
use crate::task::michelson::MichelsonScore;
use crate::task::relay::aligned_mirrors;

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

/// A simulated camera looking at one task's scene.
pub struct SimCamera {
    task: TaskKind,
    scene: Scene,
    frames: u64,
    centred_tolerance_px: f64,
    /// The size frames are delivered at, when smaller than the scene's camera.
    frame_size: Option<[u32; 2]>,
}

impl SimCamera {
    /// The scene of `task` for `seed` (hidden offsets drawn from the scenario), with
    /// frames at `frame_size` (width, height) when given.
    pub fn new(
        task: TaskKind,
        scenario: &ScenarioFile,
        seed: u64,
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
        Ok(Self {
            task,
            scene,
            frames: 0,
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

    pub fn task(&self) -> TaskKind {
        self.task
    }

    /// The next frame, of the mirrors at the true shaft positions `shafts`.
    pub fn render(&mut self, shafts: &[i32]) -> anyhow::Result<Frame> {
        let index = self.frames;
        self.frames += 1;
        let frame = match &self.scene {
            Scene::Michelson(_, Some(binned)) => return Ok(binned.render(shafts, index)),
            Scene::Michelson(scene, None) => scene.render(shafts, index),
            Scene::Cavity(scene) => scene.render(shafts, index),
            Scene::Relay { relay, pose, .. } => relay.render(shafts, pose, index),
        };
        match self.frame_size {
            Some([width, height]) => area_average(&frame, width, height),
            None => Ok(frame),
        }
    }

    /// The relay's camera station (C8 for the other tasks).
    pub fn station(&self) -> Station {
        match &self.scene {
            Scene::Relay { pose, .. } => pose.station,
            _ => Station::C8,
        }
    }

    /// Places the relay's camera at `station` (with a fresh placement error, also when it
    /// stays); returns whether it moved.
    pub fn place(&mut self, station: Station) -> anyhow::Result<bool> {
        let Scene::Relay {
            relay,
            pose,
            placements,
        } = &mut self.scene
        else {
            anyhow::bail!("the {} camera has no stations to move to", self.task);
        };
        let moved = pose.station != station;
        *pose = CameraPose::place(station, &relay.params().camera, placements.as_mut());
        Ok(moved)
    }

    /// The hidden score of the mirrors at `shafts`, the Michelson's commanded score from
    /// the absolute settings last commanded, `commanded`.
    pub fn score(&self, shafts: &[i32], commanded: &[i32]) -> Score {
        match &self.scene {
            Scene::Michelson(scene, _) => {
                let truth = scene.truth(shafts);
                Score::Michelson(MichelsonScore {
                    error_px: truth.error_px,
                    commanded_error_px: scene.truth(commanded).error_px,
                    beam_centres_px: truth.beam_centres_px,
                })
            }
            Scene::Cavity(scene) => {
                let truth = scene.truth(shafts);
                Score::Cavity(CavityScore {
                    error_steps: truth.error_steps,
                    success: truth.success,
                    secondary_centre_px: Some(truth.secondary_centre_px),
                })
            }
            Scene::Relay { relay, pose, .. } => {
                let truth = relay.truth(shafts);
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
