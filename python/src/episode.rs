//! One simulated alignment episode, stepped from Python: the simulated rig of a task and
//! seed (exactly the rig `optalign bench` builds for that seed), the task's rules checking
//! every action, and the hidden score read out only when asked. The Gymnasium environments
//! wrap this.

use std::path::PathBuf;
use std::sync::{Mutex, MutexGuard};

use optalign::rig::{MotorPath, Rig, SimRig};
use optalign::run::{TaskState, is_success};
use optalign::scenario::ScenarioFile;
use optalign::task::{Action, RelayAction, TaskKind};
use optalign_optics::{Frame, Station};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyByteArray;
use tokio::runtime::Runtime;

use crate::errors::{failed, invalid};
use crate::runtime;

/// What a running episode holds between steps.
struct Live {
    rig: SimRig,
    rules: TaskState,
    evaluations: usize,
    rejections_in_row: usize,
}

/// A simulated episode of one task.
#[pyclass(module = "optalign._native")]
pub struct Episode {
    task: TaskKind,
    scenario: ScenarioFile,
    motors: MotorPath,
    frame_size: Option<[u32; 2]>,
    runtime: Runtime,
    live: Mutex<Option<Live>>,
}

/// Parses a task name as the command line spells it.
pub fn parse_task(name: &str) -> PyResult<TaskKind> {
    TaskKind::ALL
        .into_iter()
        .find(|task| task.name() == name)
        .ok_or_else(|| {
            invalid(format!(
                "unknown task {name:?}: use \"michelson\", \"cavity\" or \"relay\""
            ))
        })
}

/// Parses a motor path as the command line spells it.
pub fn parse_motors(name: &str) -> PyResult<MotorPath> {
    match name {
        "in-process" => Ok(MotorPath::InProcess),
        "peer" => Ok(MotorPath::Peer),
        _ => Err(invalid(format!(
            "unknown motors {name:?}: use \"in-process\" (the firmware core in this process) or \"peer\" (a simulated controller over loopback TCP)"
        ))),
    }
}

/// Loads a scenario file, or the defaults.
pub fn load_scenario(path: Option<PathBuf>) -> PyResult<ScenarioFile> {
    ScenarioFile::load_or_default(path.as_deref()).map_err(|e| invalid(format!("{e:#}")))
}

fn steps(name: &str, value: i64) -> PyResult<i32> {
    i32::try_from(value).map_err(|_| invalid(format!("{name}={value} does not fit in motor steps")))
}

#[pymethods]
impl Episode {
    #[new]
    #[pyo3(signature = (task, scenario=None, motors="in-process", obs_size=None))]
    fn new(
        task: &str,
        scenario: Option<PathBuf>,
        motors: &str,
        obs_size: Option<(u32, u32)>,
    ) -> PyResult<Self> {
        let task = parse_task(task)?;
        let scenario = load_scenario(scenario)?;
        let frame_size = obs_size.map(|(width, height)| [width, height]);
        SimRig::check_frame_size(task, &scenario, frame_size)
            .map_err(|error| invalid(format!("obs_size: {error}")))?;
        Ok(Self {
            task,
            motors: parse_motors(motors)?,
            frame_size,
            scenario,
            runtime: runtime::single_threaded()?,
            live: Mutex::new(None),
        })
    }

    /// The observation's (height, width).
    fn frame_shape(&self) -> (u32, u32) {
        let [width, height] = self
            .frame_size
            .or(self.scenario.geometry(self.task).image_px)
            .unwrap_or_default();
        (height, width)
    }

    /// The scenario's task bounds and budgets, as JSON (`[tasks]` of the scenario file).
    fn limits_json(&self) -> PyResult<String> {
        serde_json::to_string(&self.scenario.tasks).map_err(invalid)
    }

    fn budget(&self) -> usize {
        self.scenario.tasks.budget(self.task)
    }

    /// Starts the episode of `seed` and returns the first image.
    fn reset<'py>(&self, py: Python<'py>, seed: u64) -> PyResult<Bound<'py, PyByteArray>> {
        let (live, image) = py
            .detach(|| {
                self.runtime.block_on(async {
                    let mut rig = SimRig::with_frame_size(
                        self.task,
                        &self.scenario,
                        seed,
                        self.motors,
                        self.frame_size,
                    )
                    .await?;
                    let image = rig.initial_image().await?;
                    let live = Live {
                        rig,
                        rules: TaskState::new(self.task, &self.scenario.tasks),
                        evaluations: 0,
                        rejections_in_row: 0,
                    };
                    anyhow::Ok((live, image))
                })
            })
            .map_err(failed)?;
        *self.lock()? = Some(live);
        Ok(PyByteArray::new(py, &image.to_8bit()))
    }

    /// An absolute command (Michelson, cavity); `done` ends the episode after it.
    fn act_command<'py>(
        &self,
        py: Python<'py>,
        command: Vec<i64>,
        done: bool,
    ) -> PyResult<(Option<Bound<'py, PyByteArray>>, Option<String>)> {
        let names: &[&str] = match self.task {
            TaskKind::Michelson => &optalign::task::michelson::AXIS_NAMES,
            TaskKind::Cavity => &optalign::task::cavity::AXIS_NAMES,
            TaskKind::Relay => {
                return Err(invalid(
                    "the relay takes tilts, camera moves and done, not absolute commands",
                ));
            }
        };
        if command.len() != names.len() {
            return Err(invalid(format!(
                "the {} task takes {} values ({}), got {}",
                self.task,
                names.len(),
                names.join(", "),
                command.len()
            )));
        }
        let values: Vec<i32> = names
            .iter()
            .zip(&command)
            .map(|(name, &value)| steps(name, value))
            .collect::<PyResult<_>>()?;
        let action = match self.task {
            TaskKind::Michelson => Action::Michelson {
                command: [values[0], values[1], values[2], values[3]],
                done,
            },
            _ => Action::Cavity {
                command: [values[0], values[1]],
                done,
            },
        };
        self.act(py, action, true)
    }

    /// A relative tilt of relay mirror `mirror` (0 = M1 .. 3 = M4), in steps.
    fn act_tilt<'py>(
        &self,
        py: Python<'py>,
        mirror: i64,
        vertical: i64,
        horizontal: i64,
    ) -> PyResult<(Option<Bound<'py, PyByteArray>>, Option<String>)> {
        self.relay_only("tilts")?;
        let max_step = i64::from(self.scenario.tasks.relay.max_step);
        if !(0..=3).contains(&mirror) {
            return Err(invalid(format!(
                "mirror must be 0..=3 (M1..M4), got {mirror}"
            )));
        }
        for (name, value) in [("vertical", vertical), ("horizontal", horizontal)] {
            if value.abs() > max_step {
                return Err(invalid(format!(
                    "rejected, nothing moved: M{} {name} {value:+} is outside the per-action bound [-{max_step}, {max_step}]",
                    mirror + 1
                )));
            }
        }
        let action = Action::Relay(RelayAction::Tilt {
            mirror: mirror as u8,
            vertical: steps("vertical", vertical)?,
            horizontal: steps("horizontal", horizontal)?,
        });
        self.act(py, action, false)
    }

    /// Moves the relay's camera to station `station` (0 = C1 .. 7 = C8).
    fn act_measure<'py>(
        &self,
        py: Python<'py>,
        station: i64,
    ) -> PyResult<(Option<Bound<'py, PyByteArray>>, Option<String>)> {
        self.relay_only("camera moves")?;
        let station = usize::try_from(station)
            .ok()
            .and_then(Station::from_index)
            .ok_or_else(|| invalid(format!("station must be 0..=7 (C1..C8), got {station}")))?;
        self.act(py, Action::Relay(RelayAction::Measure { station }), false)
    }

    /// Declares the relay aligned (accepted only with the camera at C8).
    fn act_done<'py>(
        &self,
        py: Python<'py>,
    ) -> PyResult<(Option<Bound<'py, PyByteArray>>, Option<String>)> {
        self.relay_only("done")?;
        self.act(py, Action::Relay(RelayAction::Done), false)
    }

    /// The task's error now: Michelson px, cavity steps, relay px at C8 (`None` while no
    /// light reaches C8). Hidden truth.
    fn error(&self) -> PyResult<Option<f64>> {
        self.with_live(|live| live.rig.score().error())
    }

    /// Whether the state now meets the task's success rule. Hidden truth.
    fn success(&self) -> PyResult<bool> {
        self.with_live(|live| is_success(&live.rig.score(), &self.scenario.tasks))
    }

    /// Evaluations spent so far.
    fn evaluations(&self) -> PyResult<usize> {
        self.with_live(|live| live.evaluations)
    }

    /// Rejected actions since the last executed one.
    fn rejections_in_row(&self) -> PyResult<usize> {
        self.with_live(|live| live.rejections_in_row)
    }

    /// The relay camera's station, 0 = C1 .. 7 = C8 (C8 for the other tasks).
    fn station(&self) -> PyResult<usize> {
        self.with_live(|live| live.rules.relay().station.index())
    }

    /// The hidden state as JSON: the score and the true shaft positions.
    fn truth_json(&self) -> PyResult<String> {
        let truth = self.with_live(
            |live| serde_json::json!({ "score": live.rig.score(), "shafts": live.rig.shafts() }),
        )?;
        Ok(truth.to_string())
    }
}

impl Episode {
    fn lock(&self) -> PyResult<MutexGuard<'_, Option<Live>>> {
        self.live
            .lock()
            .map_err(|_| PyRuntimeError::new_err("an earlier step panicked; reset the episode"))
    }

    fn with_live<T>(&self, read: impl FnOnce(&Live) -> T) -> PyResult<T> {
        self.lock()?
            .as_ref()
            .map(read)
            .ok_or_else(|| PyRuntimeError::new_err("the episode has not been reset yet"))
    }

    fn relay_only(&self, what: &str) -> PyResult<()> {
        if self.task == TaskKind::Relay {
            Ok(())
        } else {
            Err(invalid(format!(
                "{what} belong to the relay task; the {} task takes absolute commands",
                self.task
            )))
        }
    }

    /// Checks and executes one action. A rejection raises when `rejection_is_an_error`
    /// (the action lies outside the task's fixed bounds); otherwise it comes back as the
    /// reason, with no image, and spends no evaluation.
    fn act<'py>(
        &self,
        py: Python<'py>,
        action: Action,
        rejection_is_an_error: bool,
    ) -> PyResult<(Option<Bound<'py, PyByteArray>>, Option<String>)> {
        let mut guard = self.lock()?;
        let live = guard
            .as_mut()
            .ok_or_else(|| PyRuntimeError::new_err("the episode has not been reset yet"))?;
        let budget = self.budget();
        if live.evaluations >= budget {
            return Err(PyRuntimeError::new_err(format!(
                "the budget of {budget} evaluations is spent; reset the episode"
            )));
        }
        if let Err(reason) = live.rules.check(&action) {
            if rejection_is_an_error {
                return Err(invalid(reason));
            }
            live.rejections_in_row += 1;
            return Ok((None, Some(reason)));
        }
        live.rules.apply(&action);
        let image: Frame = py
            .detach(|| self.runtime.block_on(live.rig.execute(&action)))
            .map_err(failed)?
            .image;
        live.evaluations += 1;
        live.rejections_in_row = 0;
        Ok((Some(PyByteArray::new(py, &image.to_8bit())), None))
    }
}
