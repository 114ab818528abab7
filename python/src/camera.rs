//! `SimCamera`: the simulated camera of a task's rig watching a [`SimulatedPeer`]'s mounts
//! (the scene of a seed rendered from the controller's true shaft positions), and the beam
//! detector the agents use run on every frame it grabs. The Bluesky camera device triggers
//! it; an alignment plan hands its frames to the run.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

use optalign::imaging::{Picture, find_beams};
use optalign::peer::SimPeer;
use optalign::rig::{Score, SimCamera as Scene};
use optalign::run::is_success;
use optalign::scenario::ScenarioFile;
use optalign_optics::{Frame, Station};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyByteArray;

use crate::errors::{failed, invalid};
use crate::peer::SimulatedPeer;
use crate::stepper::{load_scenario, parse_task};

/// The scene and the last frame grabbed.
pub struct Shots {
    scene: Scene,
    last: Option<Arc<Frame>>,
}

/// The camera of a simulated rig.
#[pyclass(module = "optalign._native")]
pub struct SimCamera {
    peer: Arc<SimPeer>,
    scenario: ScenarioFile,
    shots: Arc<Mutex<Shots>>,
}

#[pymethods]
impl SimCamera {
    #[new]
    #[pyo3(signature = (task, seed, peer, scenario=None, obs_size=None))]
    fn new(
        task: &str,
        seed: u64,
        peer: PyRef<'_, SimulatedPeer>,
        scenario: Option<PathBuf>,
        obs_size: Option<(u32, u32)>,
    ) -> PyResult<Self> {
        let task = parse_task(task).map_err(invalid)?;
        let scenario = load_scenario(scenario).map_err(invalid)?;
        let frame_size = obs_size.map(|(width, height)| [width, height]);
        let scene = Scene::new(task, &scenario, seed, frame_size)
            .map_err(|error| invalid(format!("{error:#}")))?;
        let peer = peer.shared();
        let axes = peer.shaft_positions().len();
        if axes != task.axes() {
            return Err(invalid(format!(
                "the {task} rig moves {} axes; this controller has {axes}",
                task.axes()
            )));
        }
        Ok(Self {
            peer,
            scenario,
            shots: Arc::new(Mutex::new(Shots { scene, last: None })),
        })
    }

    /// Grabs the next frame of the mirrors where they truly are and finds the beams in it:
    /// (the frame scaled to 8 bits, its (height, width), the detector's report as JSON:
    /// background, read noise and every beam).
    fn grab<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Bound<'py, PyByteArray>, (u32, u32), String)> {
        let (pixels, shape, report) = py
            .detach(|| {
                let frame = {
                    let mut shots = self.lock()?;
                    let frame = Arc::new(shots.scene.render(&self.peer.shaft_positions())?);
                    shots.last = Some(frame.clone());
                    frame
                };
                let picture = Picture::new(&frame);
                let report = serde_json::json!({
                    "background": picture.background(),
                    "read_noise": picture.noise(),
                    "beams": find_beams(&picture),
                });
                anyhow::Ok((
                    frame.to_8bit(),
                    (frame.height(), frame.width()),
                    report.to_string(),
                ))
            })
            .map_err(failed)?;
        Ok((PyByteArray::new(py, &pixels), shape, report))
    }

    /// The hidden score of the mirrors now, as JSON (`error`: the task's error, None while
    /// no light reaches the relay's C8; `score`, `success`, `shafts`), the
    /// Michelson's commanded score from `commanded`, the absolute settings last commanded.
    /// Hidden truth: for records, never for a policy.
    fn truth_json(&self, commanded: Vec<i32>) -> PyResult<String> {
        let shafts = self.peer.shaft_positions();
        let score = self.score(&shafts, &commanded)?;
        let success = is_success(&score, &self.scenario.tasks);
        let truth = serde_json::json!({
            "error": score.error(),
            "score": score,
            "success": success,
            "shafts": shafts,
        });
        Ok(truth.to_string())
    }

    /// The relay camera's station, 0 = C1 .. 7 = C8 (C8 for the other tasks).
    fn station(&self) -> PyResult<usize> {
        Ok(self.lock().map_err(failed)?.scene.station().index())
    }

    /// Moves the relay's camera to station `station` (0 = C1 .. 7 = C8).
    fn place(&self, station: usize) -> PyResult<()> {
        let station = Station::from_index(station)
            .ok_or_else(|| invalid(format!("station must be 0..=7 (C1..C8), got {station}")))?;
        self.lock()
            .map_err(failed)?
            .scene
            .place(station)
            .map(|_| ())
            .map_err(|error| invalid(format!("{error:#}")))
    }
}

impl SimCamera {
    fn lock(&self) -> anyhow::Result<MutexGuard<'_, Shots>> {
        self.shots
            .lock()
            .map_err(|_| anyhow::anyhow!("an earlier frame panicked; make the camera anew"))
    }

    /// The hidden score of the mirrors at `shafts`.
    pub fn score(&self, shafts: &[i32], commanded: &[i32]) -> PyResult<Score> {
        let shots = self
            .lock()
            .map_err(|error| PyRuntimeError::new_err(error.to_string()))?;
        Ok(shots.scene.score(shafts, commanded))
    }

    /// What an alignment run needs of the camera: its scene and frames, and the mounts it
    /// watches.
    pub fn parts(&self) -> (Arc<Mutex<Shots>>, Arc<SimPeer>, ScenarioFile) {
        (self.shots.clone(), self.peer.clone(), self.scenario.clone())
    }
}

impl Shots {
    /// The last frame grabbed.
    pub fn last(&self) -> Option<Arc<Frame>> {
        self.last.clone()
    }

    /// The hidden score of the mirrors at `shafts`.
    pub fn score(&self, shafts: &[i32], commanded: &[i32]) -> Score {
        self.scene.score(shafts, commanded)
    }

    pub fn task(&self) -> optalign::task::TaskKind {
        self.scene.task()
    }
}
