//! `Alignment`: one optalign run carried out by a Bluesky plan. The run loop of `optalign
//! run` (`run_episode`: the policy, the task's rules, the budget, the summary) runs on a
//! thread of its own against a rig that hands every action to the plan: the plan asks for
//! the next request, moves the devices, triggers the camera and answers; the run reads the
//! frame the camera grabbed and scores the mirrors where the controller truly put them.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;

use async_trait::async_trait;
use optalign::peer::SimPeer;
use optalign::policy::{PolicyOptions, TaskBrief, build_policy};
use optalign::rig::{ControllerView, Executed, Rig, Score};
use optalign::run::{RunOptions, RunSummary, run_episode};
use optalign::task::relay::{RelayAction, axis_of};
use optalign::task::{Action, TaskKind};
use optalign_optics::Frame;
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use serde_json::json;
use tokio::sync::mpsc;

use crate::camera::{Shots, SimCamera};
use crate::errors::{failed, invalid};
use crate::runs::check_policy;
use crate::runtime;

/// What the run asks of the plan.
enum Request {
    /// Carry out an action: move, place the camera, then grab a frame.
    Execute(serde_json::Value),
    /// Stop every axis at once.
    EmergencyStop,
}

/// The plan's answer: done (the frame is the camera's last), or why not.
type Answer = Result<(), String>;

/// The rig the run drives: every action goes to the plan.
struct PlanRig {
    task: TaskKind,
    shots: Arc<Mutex<Shots>>,
    peer: Arc<SimPeer>,
    /// The absolute settings last commanded (Michelson, cavity), for the commanded score.
    commanded: Vec<i32>,
    requests: mpsc::UnboundedSender<Request>,
    answers: mpsc::UnboundedReceiver<Answer>,
}

impl PlanRig {
    fn last_frame(&self) -> anyhow::Result<Frame> {
        let shots = self
            .shots
            .lock()
            .map_err(|_| anyhow::anyhow!("the camera panicked"))?;
        let frame = shots
            .last()
            .ok_or_else(|| anyhow::anyhow!("the camera has grabbed no frame yet"))?;
        Ok(Frame::clone(&frame))
    }

    /// Sends `request` to the plan and waits for its answer.
    async fn ask(&mut self, request: Request) -> anyhow::Result<()> {
        self.requests
            .send(request)
            .map_err(|_| anyhow::anyhow!("the plan has ended"))?;
        match self.answers.recv().await {
            Some(Ok(())) => Ok(()),
            Some(Err(reason)) => Err(anyhow::anyhow!(reason)),
            None => Err(anyhow::anyhow!("the plan was stopped")),
        }
    }

    /// What the plan must do for `action`: axis moves (absolute targets of the axes whose
    /// setting changes, with the whole command, or relative deltas), a camera station, and
    /// whether it declares done.
    fn orders(&self, action: &Action) -> serde_json::Value {
        let absolute = |command: &[i32], done: bool| {
            let targets: Vec<(usize, i32)> = command
                .iter()
                .enumerate()
                .filter(|&(axis, value)| self.commanded[axis] != *value)
                .map(|(axis, &value)| (axis, value))
                .collect();
            json!({ "moves": targets, "relative": false, "done": done, "command": command })
        };
        let relative = |deltas: Vec<(usize, i32)>| {
            let moves: Vec<_> = deltas.into_iter().filter(|&(_, d)| d != 0).collect();
            json!({ "moves": moves, "relative": true, "done": false })
        };
        let mut orders = match action {
            Action::Michelson { command, done } => absolute(command, *done),
            Action::Cavity { command, done } => absolute(command, *done),
            Action::Relay(RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            }) => relative(vec![
                (axis_of(*mirror, false), *vertical),
                (axis_of(*mirror, true), *horizontal),
            ]),
            Action::Relay(RelayAction::TiltAll { deltas }) => {
                relative(deltas.iter().copied().enumerate().collect())
            }
            Action::Relay(RelayAction::Measure { station }) => {
                json!({ "moves": [], "relative": false, "done": false, "station": station.index() })
            }
            Action::Relay(RelayAction::Done) => {
                json!({ "moves": [], "relative": false, "done": true })
            }
        };
        orders["action"] = json!(action.describe());
        orders
    }
}

#[async_trait]
impl Rig for PlanRig {
    fn task(&self) -> TaskKind {
        self.task
    }

    async fn initial_image(&mut self) -> anyhow::Result<Frame> {
        self.last_frame()
    }

    async fn execute(&mut self, action: &Action) -> anyhow::Result<Executed> {
        self.ask(Request::Execute(self.orders(action))).await?;
        if let Action::Michelson { command, .. } = action {
            self.commanded = command.to_vec();
        }
        if let Action::Cavity { command, .. } = action {
            self.commanded = command.to_vec();
        }
        Ok(Executed {
            image: self.last_frame()?,
            motor_time_s: 0.0,
            camera_time_s: 0.0,
        })
    }

    fn score(&self) -> Score {
        let shafts = self.peer.shaft_positions();
        match self.shots.lock() {
            Ok(shots) => shots.score(&shafts, &self.commanded),
            Err(poisoned) => poisoned.into_inner().score(&shafts, &self.commanded),
        }
    }

    async fn emergency_stop(&mut self) -> anyhow::Result<()> {
        self.ask(Request::EmergencyStop).await
    }

    async fn controllers(&mut self) -> anyhow::Result<Vec<ControllerView>> {
        Ok(Vec::new())
    }
}

/// A run under way, driven by a plan.
#[pyclass(module = "optalign._native")]
pub struct Alignment {
    requests: Mutex<mpsc::UnboundedReceiver<Request>>,
    answers: Mutex<Option<mpsc::UnboundedSender<Answer>>>,
    run: Mutex<Option<JoinHandle<anyhow::Result<RunSummary>>>>,
    budget: usize,
}

#[pymethods]
impl Alignment {
    /// Starts a run of `policy` on the rig `camera` watches (its controller must be the
    /// simulated one of the rig); the camera must have grabbed the first frame.
    #[new]
    #[pyo3(signature = (policy, seed, camera, scenario=None))]
    fn new(
        policy: &str,
        seed: u64,
        camera: PyRef<'_, SimCamera>,
        scenario: Option<PathBuf>,
    ) -> PyResult<Self> {
        check_policy(policy)?;
        let (shots, peer, camera_scenario) = camera.parts();
        let scenario = match scenario {
            Some(path) => crate::stepper::load_scenario(Some(path)).map_err(invalid)?,
            None => camera_scenario,
        };
        let task = shots
            .lock()
            .map_err(|_| PyRuntimeError::new_err("the camera panicked"))?
            .task();
        let brief = TaskBrief::new(task, &scenario.tasks, scenario.geometry(task));
        let options = PolicyOptions { seed, vlm: None };
        let mut built = build_policy(policy, &brief, &options).map_err(failed)?;
        let (request_tx, request_rx) = mpsc::unbounded_channel();
        let (answer_tx, answer_rx) = mpsc::unbounded_channel();
        let mut rig = PlanRig {
            task,
            shots,
            peer,
            commanded: vec![0; task.axes()],
            requests: request_tx,
            answers: answer_rx,
        };
        let runtime = runtime::single_threaded()?;
        let budget = scenario.tasks.budget(task);
        let run = std::thread::Builder::new()
            .name("optalign-alignment".into())
            .spawn(move || {
                let options = RunOptions {
                    seed,
                    save_frames: false,
                    ..RunOptions::default()
                };
                runtime.block_on(run_episode(
                    &mut rig,
                    built.policy.as_mut(),
                    built.objective.as_ref(),
                    &scenario.tasks,
                    &options,
                ))
            })
            .map_err(|error| PyRuntimeError::new_err(format!("cannot start the run: {error}")))?;
        Ok(Self {
            requests: Mutex::new(request_rx),
            answers: Mutex::new(Some(answer_tx)),
            run: Mutex::new(Some(run)),
            budget,
        })
    }

    /// The evaluation budget.
    #[getter]
    fn budget(&self) -> usize {
        self.budget
    }

    /// Waits for the run's next request (GIL released): `("execute", orders as JSON)`,
    /// `("emergency_stop", "")`, or `("finished", the run summary as JSON)` once the run has
    /// ended.
    fn next(&self, py: Python<'_>) -> PyResult<(String, String)> {
        let request = py.detach(|| {
            self.requests
                .lock()
                .map(|mut requests| requests.blocking_recv())
                .map_err(|_| PyRuntimeError::new_err("an earlier request panicked"))
        })?;
        match request {
            Some(Request::Execute(orders)) => Ok(("execute".into(), orders.to_string())),
            Some(Request::EmergencyStop) => Ok(("emergency_stop".into(), String::new())),
            None => {
                let summary = self.finish(py)?;
                Ok(("finished".into(), summary))
            }
        }
    }

    /// Answers the last request: carried out (the camera has grabbed the frame after it).
    fn done(&self) -> PyResult<()> {
        self.answer(Ok(()))
    }

    /// Answers the last request: it failed, for `reason` (the run ends, recording it).
    fn failed(&self, reason: String) -> PyResult<()> {
        self.answer(Err(reason))
    }

    /// Ends the run without waiting: the request waiting for an answer fails ("the plan
    /// was stopped") and the run closes, recording that.
    fn close(&self) {
        if let Ok(mut answers) = self.answers.lock() {
            answers.take();
        }
    }
}

impl Alignment {
    fn answer(&self, answer: Answer) -> PyResult<()> {
        let answers = self
            .answers
            .lock()
            .map_err(|_| PyRuntimeError::new_err("an earlier answer panicked"))?;
        answers
            .as_ref()
            .ok_or_else(|| PyRuntimeError::new_err("the run was closed"))?
            .send(answer)
            .map_err(|_| PyRuntimeError::new_err("the run has ended"))
    }

    /// Waits for the run's thread and returns its summary as JSON.
    fn finish(&self, py: Python<'_>) -> PyResult<String> {
        let handle = self
            .run
            .lock()
            .map_err(|_| PyRuntimeError::new_err("an earlier close panicked"))?
            .take()
            .ok_or_else(|| PyRuntimeError::new_err("the run's summary was already taken"))?;
        let summary = py
            .detach(|| handle.join())
            .map_err(|_| PyRuntimeError::new_err("the run panicked"))?
            .map_err(failed)?;
        serde_json::to_string(&summary).map_err(invalid)
    }
}
