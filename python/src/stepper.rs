//! One simulated alignment episode without Python: the simulated rig of a task and seed
//! (exactly the rig `optalign bench` builds for that seed), the task's rules checking every
//! action, and the hidden score read out only when asked. The Gymnasium environment
//! ([`crate::episode`]) and the native vector environment ([`crate::vector`]) both step
//! this, so a batch gives exactly the single environment's episodes.

use std::path::PathBuf;
use std::sync::Arc;

use optalign::rig::{MotorPath, Rig, Score, SimCamera, SimRig};
use optalign::run::{TaskState, is_success};
use optalign::scenario::ScenarioFile;
use optalign::task::{Action, TaskKind};
use pyo3::PyErr;
use pyo3::exceptions::PyRuntimeError;
use tokio::runtime::Runtime;

use crate::errors::{failed, invalid};
use crate::runtime;

/// What every episode of one environment shares: the task, the scenario, the motor path
/// and the size frames are delivered at.
pub struct Setup {
    pub task: TaskKind,
    pub scenario: ScenarioFile,
    pub motors: MotorPath,
    pub frame_size: Option<[u32; 2]>,
}

/// What stepping an episode can fail with.
pub enum StepError {
    /// The caller's mistake (an action outside the task's bounds, no reset yet): the
    /// message says which.
    Invalid(String),
    /// The episode cannot go on (the budget is spent, no reset yet).
    State(String),
    /// The simulation failed, with its chain of causes.
    Failed(anyhow::Error),
}

impl From<StepError> for PyErr {
    fn from(error: StepError) -> Self {
        match error {
            StepError::Invalid(message) => invalid(message),
            StepError::State(message) => PyRuntimeError::new_err(message),
            StepError::Failed(error) => failed(error),
        }
    }
}

/// An episode's state after a step or reset: (true error, success, evaluations, rejected
/// actions in a row). Hidden truth in the first two: the Python side turns them into the
/// reward and the termination.
pub type State = (Option<f64>, bool, usize, usize);

/// What an action came to: the next image (8-bit, row by row), or the reason it was
/// rejected without moving anything or spending an evaluation.
pub enum Acted {
    Image(Vec<u8>),
    Rejected(String),
}

/// What a running episode holds between steps.
pub struct Live {
    pub rig: SimRig,
    pub rules: TaskState,
    pub evaluations: usize,
    pub rejections_in_row: usize,
}

/// An episode of one [`Setup`], with the async runtime its rig runs on.
pub struct Stepper {
    setup: Arc<Setup>,
    runtime: Runtime,
    live: Option<Live>,
}

/// Parses a task name as the command line spells it.
pub fn parse_task(name: &str) -> Result<TaskKind, String> {
    TaskKind::ALL
        .into_iter()
        .find(|task| task.name() == name)
        .ok_or_else(|| format!("unknown task {name:?}: use \"michelson\", \"cavity\" or \"relay\""))
}

/// Parses a motor path as the command line spells it.
pub fn parse_motors(name: &str) -> Result<MotorPath, String> {
    match name {
        "in-process" => Ok(MotorPath::InProcess),
        "peer" => Ok(MotorPath::Peer),
        _ => Err(format!(
            "unknown motors {name:?}: use \"in-process\" (the firmware core in this process) or \"peer\" (a simulated controller over loopback TCP)"
        )),
    }
}

/// Loads a scenario file, or the defaults.
pub fn load_scenario(path: Option<PathBuf>) -> Result<ScenarioFile, String> {
    ScenarioFile::load_or_default(path.as_deref()).map_err(|e| format!("{e:#}"))
}

/// A value in motor steps, or why it is none.
pub fn steps(name: &str, value: i64) -> Result<i32, String> {
    i32::try_from(value).map_err(|_| format!("{name}={value} does not fit in motor steps"))
}

impl Setup {
    /// The setup of `task` ("michelson", ...) under a scenario file (or the defaults), on
    /// `motors`, with frames of `obs_size` (width, height) when given.
    pub fn new(
        task: &str,
        scenario: Option<PathBuf>,
        motors: &str,
        obs_size: Option<(u32, u32)>,
    ) -> Result<Self, String> {
        let task = parse_task(task)?;
        let scenario = load_scenario(scenario)?;
        let frame_size = obs_size.map(|(width, height)| [width, height]);
        SimCamera::check_frame_size(task, &scenario, frame_size)
            .map_err(|error| format!("obs_size: {error}"))?;
        Ok(Self {
            task,
            motors: parse_motors(motors)?,
            frame_size,
            scenario,
        })
    }

    /// The observation's (height, width).
    pub fn frame_shape(&self) -> (u32, u32) {
        let [width, height] = self
            .frame_size
            .or(self.scenario.geometry(self.task).image_px)
            .unwrap_or_default();
        (height, width)
    }

    /// Bytes of one 8-bit observation.
    pub fn frame_len(&self) -> usize {
        let (height, width) = self.frame_shape();
        height as usize * width as usize
    }

    pub fn budget(&self) -> usize {
        self.scenario.tasks.budget(self.task)
    }

    /// The scenario's task bounds and budgets, as JSON (`[tasks]` of the scenario file).
    pub fn limits_json(&self) -> Result<String, String> {
        serde_json::to_string(&self.scenario.tasks).map_err(|e| e.to_string())
    }

    /// The absolute command of the Michelson or the cavity, one setting per axis; `done`
    /// declares the task done after it.
    pub fn command(&self, command: &[i64], done: bool) -> Result<Action, String> {
        let names: &[&str] = match self.task {
            TaskKind::Michelson => &optalign::task::michelson::AXIS_NAMES,
            TaskKind::Cavity => &optalign::task::cavity::AXIS_NAMES,
            TaskKind::Relay => {
                return Err(
                    "the relay takes tilts, camera moves and done, not absolute commands".into(),
                );
            }
        };
        if command.len() != names.len() {
            return Err(format!(
                "the {} task takes {} values ({}), got {}",
                self.task,
                names.len(),
                names.join(", "),
                command.len()
            ));
        }
        let values: Vec<i32> = names
            .iter()
            .zip(command)
            .map(|(name, &value)| steps(name, value))
            .collect::<Result<_, _>>()?;
        Ok(match self.task {
            TaskKind::Michelson => Action::Michelson {
                command: [values[0], values[1], values[2], values[3]],
                done,
            },
            _ => Action::Cavity {
                command: [values[0], values[1]],
                done,
            },
        })
    }

    /// Whether `action` lies inside the task's fixed bounds (those that do not depend on
    /// an episode's history).
    pub fn check_bounds(&self, action: &Action) -> Result<(), String> {
        TaskState::new(self.task, &self.scenario.tasks).check(action)
    }
}

impl Stepper {
    pub fn new(setup: Arc<Setup>) -> Result<Self, PyErr> {
        Ok(Self {
            setup,
            runtime: runtime::single_threaded()?,
            live: None,
        })
    }

    /// Starts the episode of `seed`; returns the first image.
    pub fn reset(&mut self, seed: u64) -> anyhow::Result<Vec<u8>> {
        let setup = &self.setup;
        let (live, image) = self.runtime.block_on(async {
            let mut rig = SimRig::with_frame_size(
                setup.task,
                &setup.scenario,
                seed,
                setup.motors,
                setup.frame_size,
            )
            .await?;
            let image = rig.initial_image().await?;
            let live = Live {
                rig,
                rules: TaskState::new(setup.task, &setup.scenario.tasks),
                evaluations: 0,
                rejections_in_row: 0,
            };
            anyhow::Ok((live, image))
        })?;
        self.live = Some(live);
        Ok(image.to_8bit())
    }

    /// The running episode.
    pub fn live(&self) -> Result<&Live, StepError> {
        self.live
            .as_ref()
            .ok_or_else(|| StepError::State("the episode has not been reset yet".into()))
    }

    /// The hidden score of the state now.
    pub fn score(&self) -> Result<Score, StepError> {
        Ok(self.live()?.rig.score())
    }

    /// Whether the state now meets the task's success rule. Hidden truth.
    pub fn success(&self) -> Result<bool, StepError> {
        Ok(is_success(&self.score()?, &self.setup.scenario.tasks))
    }

    /// The state after the last step or reset.
    pub fn state(&self) -> Result<State, StepError> {
        let live = self.live()?;
        let score = live.rig.score();
        Ok((
            score.error(),
            is_success(&score, &self.setup.scenario.tasks),
            live.evaluations,
            live.rejections_in_row,
        ))
    }

    /// The hidden state as JSON: the score and the true shaft positions.
    pub fn truth_json(&self) -> Result<String, StepError> {
        let live = self.live()?;
        let truth = serde_json::json!({ "score": live.rig.score(), "shafts": live.rig.shafts() });
        Ok(truth.to_string())
    }

    /// Checks and executes one action. A rejection is an error when
    /// `rejection_is_an_error` (the action lies outside the task's fixed bounds);
    /// otherwise it comes back as the reason and spends no evaluation.
    pub fn act(
        &mut self,
        action: &Action,
        rejection_is_an_error: bool,
    ) -> Result<Acted, StepError> {
        let budget = self.setup.budget();
        let live = self
            .live
            .as_mut()
            .ok_or_else(|| StepError::State("the episode has not been reset yet".into()))?;
        if live.evaluations >= budget {
            return Err(StepError::State(format!(
                "the budget of {budget} evaluations is spent; reset the episode"
            )));
        }
        if let Err(reason) = live.rules.check(action) {
            if rejection_is_an_error {
                return Err(StepError::Invalid(reason));
            }
            live.rejections_in_row += 1;
            return Ok(Acted::Rejected(reason));
        }
        live.rules.apply(action);
        let image = self
            .runtime
            .block_on(live.rig.execute(action))
            .map_err(StepError::Failed)?
            .image;
        live.evaluations += 1;
        live.rejections_in_row = 0;
        Ok(Acted::Image(image.to_8bit()))
    }
}
