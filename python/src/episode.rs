//! One simulated alignment episode stepped from Python, the Gymnasium environments' core:
//! a [`Stepper`] behind a lock, with the GIL released while the rig moves and renders.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

use optalign::task::{Action, RelayAction, TaskKind};
use optalign_optics::Station;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyByteArray;

use crate::errors::{failed, invalid};
use crate::stepper::{Acted, Setup, State, StepError, Stepper, steps};

/// A simulated episode of one task.
#[pyclass(module = "optalign._native")]
pub struct Episode {
    setup: Arc<Setup>,
    stepper: Mutex<Stepper>,
}

/// What a step hands Python: the next image, or the reason the action was rejected, and
/// the episode's state after it.
type Stepped<'py> = (Option<Bound<'py, PyByteArray>>, Option<String>, State);

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
        let setup = Arc::new(Setup::new(task, scenario, motors, obs_size).map_err(invalid)?);
        Ok(Self {
            stepper: Mutex::new(Stepper::new(setup.clone())?),
            setup,
        })
    }

    /// The observation's (height, width).
    fn frame_shape(&self) -> (u32, u32) {
        self.setup.frame_shape()
    }

    /// The scenario's task bounds and budgets, as JSON (`[tasks]` of the scenario file).
    fn limits_json(&self) -> PyResult<String> {
        self.setup.limits_json().map_err(invalid)
    }

    fn budget(&self) -> usize {
        self.setup.budget()
    }

    /// Starts the episode of `seed` and returns the first image.
    fn reset<'py>(&self, py: Python<'py>, seed: u64) -> PyResult<Bound<'py, PyByteArray>> {
        let mut guard = self.lock()?;
        let stepper: &mut Stepper = &mut guard;
        let image = py.detach(|| stepper.reset(seed)).map_err(failed)?;
        Ok(PyByteArray::new(py, &image))
    }

    /// An absolute command (Michelson, cavity); `done` ends the episode after it.
    fn act_command<'py>(
        &self,
        py: Python<'py>,
        command: Vec<i64>,
        done: bool,
    ) -> PyResult<Stepped<'py>> {
        let action = self.setup.command(&command, done).map_err(invalid)?;
        self.act(py, action, true)
    }

    /// A relative tilt of relay mirror `mirror` (0 = M1 .. 3 = M4), in steps.
    fn act_tilt<'py>(
        &self,
        py: Python<'py>,
        mirror: i64,
        vertical: i64,
        horizontal: i64,
    ) -> PyResult<Stepped<'py>> {
        self.relay_only("tilts")?;
        let max_step = i64::from(self.setup.scenario.tasks.relay.max_step);
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
            vertical: steps("vertical", vertical).map_err(invalid)?,
            horizontal: steps("horizontal", horizontal).map_err(invalid)?,
        });
        self.act(py, action, false)
    }

    /// Moves the relay's camera to station `station` (0 = C1 .. 7 = C8).
    fn act_measure<'py>(&self, py: Python<'py>, station: i64) -> PyResult<Stepped<'py>> {
        self.relay_only("camera moves")?;
        let station = usize::try_from(station)
            .ok()
            .and_then(Station::from_index)
            .ok_or_else(|| invalid(format!("station must be 0..=7 (C1..C8), got {station}")))?;
        self.act(py, Action::Relay(RelayAction::Measure { station }), false)
    }

    /// Declares the relay aligned (accepted only with the camera at C8).
    fn act_done<'py>(&self, py: Python<'py>) -> PyResult<Stepped<'py>> {
        self.relay_only("done")?;
        self.act(py, Action::Relay(RelayAction::Done), false)
    }

    /// The task's error now: Michelson px, cavity steps, relay px at C8 (`None` while no
    /// light reaches C8). Hidden truth.
    fn error(&self) -> PyResult<Option<f64>> {
        Ok(self.lock()?.score()?.error())
    }

    /// Whether the state now meets the task's success rule. Hidden truth.
    fn success(&self) -> PyResult<bool> {
        Ok(self.lock()?.success()?)
    }

    /// Evaluations spent so far.
    fn evaluations(&self) -> PyResult<usize> {
        Ok(self.lock()?.live()?.evaluations)
    }

    /// The relay camera's station, 0 = C1 .. 7 = C8 (C8 for the other tasks).
    fn station(&self) -> PyResult<usize> {
        Ok(self.lock()?.live()?.rules.relay().station.index())
    }

    /// The hidden state as JSON: the score and the true shaft positions.
    fn truth_json(&self) -> PyResult<String> {
        Ok(self.lock()?.truth_json()?)
    }
}

impl Episode {
    fn lock(&self) -> PyResult<MutexGuard<'_, Stepper>> {
        self.stepper
            .lock()
            .map_err(|_| PyRuntimeError::new_err("an earlier step panicked; reset the episode"))
    }

    fn relay_only(&self, what: &str) -> PyResult<()> {
        if self.setup.task == TaskKind::Relay {
            Ok(())
        } else {
            Err(invalid(format!(
                "{what} belong to the relay task; the {} task takes absolute commands",
                self.setup.task
            )))
        }
    }

    /// Checks and executes one action with the GIL released. A rejection raises when
    /// `rejection_is_an_error` (the action lies outside the task's fixed bounds);
    /// otherwise it comes back as the reason, with no image, and spends no evaluation.
    fn act<'py>(
        &self,
        py: Python<'py>,
        action: Action,
        rejection_is_an_error: bool,
    ) -> PyResult<Stepped<'py>> {
        let mut guard = self.lock()?;
        let stepper: &mut Stepper = &mut guard;
        let acted: Result<Acted, StepError> =
            py.detach(|| stepper.act(&action, rejection_is_an_error));
        let state = stepper.state()?;
        Ok(match acted? {
            Acted::Image(image) => (Some(PyByteArray::new(py, &image)), None, state),
            Acted::Rejected(reason) => (None, Some(reason), state),
        })
    }
}
