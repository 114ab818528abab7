//! The run loop: policy decides, the task validates, the rig executes, the next image goes
//! back to the policy; every evaluation is scored from the rig's state and appended to the
//! transcript before the next one, so a crash never loses the log.

mod summary;
mod transcript;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

pub use summary::{EndedBy, Failure, RunSummary, is_success, summarize};
pub use transcript::{SUMMARY_FILE, StepRecord, Transcript};

use anyhow::Context;

use crate::monitor::RunMonitor;
use crate::policy::{Feedback, Observation, Policy, PrivilegedObjective};
use crate::rig::{Rig, Score};
use crate::scenario::ScenarioFile;
use crate::task::relay::RelayState;
use crate::task::{Action, TaskKind, TaskLimits};

/// How a run is recorded and bounded.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Where the transcript, summary and frames go; nothing is written when `None`.
    pub out_dir: Option<PathBuf>,
    /// Save every frame as a PNG next to the transcript.
    pub save_frames: bool,
    /// A policy that sends this many rejected actions in a row ends the run.
    pub max_consecutive_rejections: usize,
    /// Seed number, for the records.
    pub seed: u64,
    /// The live monitor watching this run: it gets every step and can pause or stop it.
    pub monitor: Option<RunMonitor>,
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            out_dir: None,
            save_frames: true,
            max_consecutive_rejections: 10,
            seed: 0,
            monitor: None,
        }
    }
}

/// The task's bookkeeping during a run: validates actions before they reach the rig.
pub struct TaskState {
    task: TaskKind,
    limits: TaskLimits,
    relay: RelayState,
}

impl TaskState {
    /// The state at the start of a run of `task` under `limits`.
    pub fn new(task: TaskKind, limits: &TaskLimits) -> Self {
        Self {
            task,
            limits: limits.clone(),
            relay: RelayState::default(),
        }
    }

    /// The relay's cumulative commands and camera station (default for the other tasks).
    pub fn relay(&self) -> &RelayState {
        &self.relay
    }

    /// Checks an action against the task and its bounds; the reason says what was wrong.
    pub fn check(&self, action: &Action) -> Result<(), String> {
        if action.task() != self.task {
            return Err(format!(
                "rejected: this is the {} task, not {}",
                self.task,
                action.task()
            ));
        }
        match action {
            Action::Michelson { command, .. } => self.limits.michelson.check(command),
            Action::Cavity { command, .. } => self.limits.cavity.check(command),
            Action::Relay(relay) => self.relay.check(&self.limits.relay, relay),
        }
    }

    /// Records an action that passed [`Self::check`].
    pub fn apply(&mut self, action: &Action) {
        if let Action::Relay(relay) = action {
            self.relay.apply(relay);
        }
    }
}

/// Runs one episode to `done`, the end of the budget, or a policy failure.
pub async fn run_episode(
    rig: &mut dyn Rig,
    policy: &mut dyn Policy,
    objective: Option<&PrivilegedObjective>,
    limits: &TaskLimits,
    options: &RunOptions,
) -> anyhow::Result<RunSummary> {
    let task = rig.task();
    let policy_name = policy.name();
    let budget = limits.budget(task);
    let mut state = TaskState::new(task, limits);
    let monitor = options.monitor.as_ref();
    let mut transcript = match &options.out_dir {
        Some(dir) => Some(Transcript::create(
            dir,
            task,
            &policy_name,
            options.seed,
            budget,
            monitor.cloned(),
        )?),
        None => None,
    };
    if let Some(monitor) = monitor {
        let frames = (options.save_frames)
            .then(|| transcript.as_ref().map(|t| t.dir().join("frames")))
            .flatten();
        monitor.begin(
            &task.to_string(),
            &policy_name,
            options.seed,
            budget,
            frames,
        );
    }
    let summary_of = |scores: &[Score], records: &[StepRecord], declared_done, failure| {
        summarize(
            task,
            &policy_name,
            options.seed,
            limits,
            scores,
            records,
            declared_done,
            failure,
        )
    };
    let mut scores: Vec<Score> = Vec::new();
    let mut records: Vec<StepRecord> = Vec::new();
    let mut image = match rig.initial_image().await {
        Ok(image) => Arc::new(image),
        Err(error) => {
            let failed = rig_failure("the rig produced no first image", &error);
            let failure = recorded(transcript.as_mut(), 0, failed, None)?;
            let summary = summary_of(&scores, &records, false, Some(failure));
            return finish(transcript, monitor, summary);
        }
    };
    scores.push(rig.score());
    let mut image_path = save_frame(transcript.as_mut(), options, 0, &image)?;
    if let (Some(transcript), Some(score)) = (transcript.as_mut(), scores.last()) {
        transcript.start_state(score, image_path.as_deref())?;
    }
    if let (Some(objective), Some(score)) = (objective, scores.last()) {
        objective.publish(score.objective());
    }
    if let (Some(monitor), Some(score)) = (monitor, scores.last()) {
        monitor.start(image.clone(), score);
        show_controllers(rig, monitor).await;
    }
    let mut feedback = Feedback::Start;
    let mut evaluations = 0usize;
    let mut consecutive_rejections = 0usize;
    let mut declared_done = false;
    let mut failure = None;
    let mut stop = None;
    while evaluations < budget {
        let gate =
            operator_gate(monitor, transcript.as_mut(), evaluations, GatePoint::Decide).await?;
        let let_through = match gate {
            (Some(reason), _) => {
                stop = Some(reason);
                break;
            }
            (None, single) => single,
        };
        let observation = Observation {
            evaluations_used: evaluations,
            remaining: budget - evaluations,
            image: image.clone(),
            image_path: image_path.clone(),
            feedback: feedback.clone(),
        };
        let decided = tokio::select! {
            biased;
            reason = stop_signal(monitor) => {
                stop = Some(reason);
                break;
            }
            decided = policy.decide(&observation) => decided,
        };
        let decision = match decided {
            Ok(decision) => decision,
            Err(error) => {
                let failed = Failure {
                    by: EndedBy::Policy,
                    reason: format!("policy failed: {}", error.message),
                };
                failure = Some(recorded(
                    transcript.as_mut(),
                    evaluations,
                    failed,
                    error.record,
                )?);
                break;
            }
        };
        if let Err(reason) = state.check(&decision.action) {
            consecutive_rejections += 1;
            let record = StepRecord::rejected(evaluations, &decision, &reason);
            if let Some(transcript) = transcript.as_mut() {
                transcript.append(&record)?;
            }
            if let Some(monitor) = monitor {
                monitor.step(&record, None);
            }
            records.push(record);
            feedback = Feedback::Rejected {
                action: decision.action,
                reason,
            };
            if consecutive_rejections >= options.max_consecutive_rejections {
                failure = Some(Failure {
                    by: EndedBy::Rejections,
                    reason: format!(
                        "the policy sent {consecutive_rejections} invalid actions in a row; the run was ended"
                    ),
                });
                break;
            }
            continue;
        }
        consecutive_rejections = 0;
        let point = GatePoint::Execute { let_through };
        if let (Some(reason), _) =
            operator_gate(monitor, transcript.as_mut(), evaluations, point).await?
        {
            stop = Some(reason);
            break;
        }
        state.apply(&decision.action);
        let executed = tokio::select! {
            biased;
            reason = stop_signal(monitor) => {
                stop = Some(reason);
                break;
            }
            executed = rig.execute(&decision.action) => executed,
        };
        let executed = match executed {
            Ok(executed) => executed,
            Err(error) => {
                let what = format!("executing {}", decision.action.describe());
                let failed = rig_failure(&what, &error);
                failure = Some(recorded(transcript.as_mut(), evaluations, failed, None)?);
                break;
            }
        };
        evaluations += 1;
        image_path = save_frame(transcript.as_mut(), options, evaluations, &executed.image)?;
        let score = rig.score();
        if let Some(objective) = objective {
            objective.publish(score.objective());
        }
        scores.push(score);
        let best = summary::best_error(&scores);
        let record = StepRecord::executed(
            evaluations,
            &decision,
            &executed,
            score,
            best,
            image_path.as_deref(),
        );
        if let Some(transcript) = transcript.as_mut() {
            transcript.append(&record)?;
        }
        image = Arc::new(executed.image);
        if let Some(monitor) = monitor {
            monitor.step(&record, Some(image.clone()));
            show_controllers(rig, monitor).await;
        }
        records.push(record);
        if decision.action.is_done() {
            declared_done = true;
            break;
        }
        feedback = Feedback::Executed {
            action: decision.action,
        };
    }
    if let Some(reason) = stop {
        failure = Some(Failure {
            by: EndedBy::Operator,
            reason: emergency_stop(rig, monitor, transcript.as_mut(), evaluations, &reason).await?,
        });
    }
    let summary = summary_of(&scores, &records, declared_done, failure);
    finish(transcript, monitor, summary)
}

/// A failure of the rig while `what`, with its whole chain of causes.
fn rig_failure(what: &str, error: &anyhow::Error) -> Failure {
    Failure {
        by: EndedBy::Rig,
        reason: format!("{what}: {error:#}"),
    }
}

/// Writes `failure` (with what the failing part did, `record`) into the transcript at
/// `evaluation`; returns it for the summary.
fn recorded(
    transcript: Option<&mut Transcript>,
    evaluation: usize,
    failure: Failure,
    record: Option<serde_json::Value>,
) -> anyhow::Result<Failure> {
    if let Some(transcript) = transcript {
        transcript.failure(evaluation, &failure, record)?;
    }
    Ok(failure)
}

/// Writes the closing line and summary, and tells the monitor.
fn finish(
    mut transcript: Option<Transcript>,
    monitor: Option<&RunMonitor>,
    summary: RunSummary,
) -> anyhow::Result<RunSummary> {
    if let Some(transcript) = transcript.as_mut() {
        transcript.finish(&summary)?;
    }
    if let Some(monitor) = monitor {
        monitor.finish(&summary);
    }
    Ok(summary)
}

/// Resolves with the reason when the operator stops the run; never without a monitor.
async fn stop_signal(monitor: Option<&RunMonitor>) -> String {
    match monitor {
        Some(monitor) => monitor.stopped().await,
        None => std::future::pending().await,
    }
}

/// Where in an evaluation the operator's gate sits.
#[derive(Clone, Copy, PartialEq)]
enum GatePoint {
    /// Before the policy decides.
    Decide,
    /// Before the decided action runs; `let_through` when the operator let this one
    /// action through a pause at the decide gate.
    Execute { let_through: bool },
}

/// Before a decision and before its action: holds the run while the operator has it
/// paused (the hold and its release logged). Returns the stop reason when the operator
/// stopped the run, and whether this evaluation was let through a pause as a single step.
async fn operator_gate(
    monitor: Option<&RunMonitor>,
    mut transcript: Option<&mut Transcript>,
    evaluations: usize,
    point: GatePoint,
) -> anyhow::Result<(Option<String>, bool)> {
    let Some(monitor) = monitor else {
        return Ok((None, false));
    };
    let control = monitor.control();
    let passes = point == GatePoint::Execute { let_through: true };
    let mut single = passes;
    if control.paused && control.stop.is_none() && !passes {
        if let Some(transcript) = transcript.as_mut() {
            transcript.pause(evaluations)?;
        }
        monitor.show_paused(true);
        let held = Instant::now();
        single = monitor.released().await;
        if monitor.control().stop.is_none() {
            if let Some(transcript) = transcript {
                transcript.resume(evaluations, held.elapsed().as_secs_f64(), single)?;
            }
            monitor.show_paused(monitor.control().paused);
        }
    }
    Ok((monitor.control().stop, single))
}

/// Stops every controller of the rig at once and records it; returns the run's reason
/// for ending (with the stop's own failure, if it failed).
async fn emergency_stop(
    rig: &mut dyn Rig,
    monitor: Option<&RunMonitor>,
    transcript: Option<&mut Transcript>,
    evaluations: usize,
    reason: &str,
) -> anyhow::Result<String> {
    let stopped = rig.emergency_stop().await;
    let stop_error = stopped.as_ref().err().map(|e| format!("{e:#}"));
    let controllers = match rig.controllers().await {
        Ok(controllers) => controllers,
        Err(error) => {
            tracing::warn!("no controller state after the emergency stop: {error:#}");
            Vec::new()
        }
    };
    if let Some(transcript) = transcript {
        transcript.stop(evaluations, reason, stop_error.as_deref(), &controllers)?;
    }
    if let Some(monitor) = monitor {
        monitor.set_controllers(controllers);
    }
    Ok(match stop_error {
        None => reason.to_owned(),
        Some(error) => format!("{reason}; the emergency stop failed: {error}"),
    })
}

/// Shows the controllers' state on the monitor (a failed status read only leaves it stale).
async fn show_controllers(rig: &mut dyn Rig, monitor: &RunMonitor) {
    match rig.controllers().await {
        Ok(controllers) => monitor.set_controllers(controllers),
        Err(error) => tracing::warn!("no controller state for the monitor: {error:#}"),
    }
}

fn save_frame(
    transcript: Option<&mut Transcript>,
    options: &RunOptions,
    evaluation: usize,
    image: &optalign_optics::Frame,
) -> anyhow::Result<Option<PathBuf>> {
    match transcript {
        Some(transcript) if options.save_frames => {
            transcript.save_frame(evaluation, image).map(Some)
        }
        _ => Ok(None),
    }
}

/// The file in a run folder that holds the scenario the run used.
pub const SCENARIO_FILE: &str = "scenario.toml";

/// Records the scenario a run used in its folder, so it can be repeated alone.
pub fn record_scenario(dir: &Path, scenario: &ScenarioFile) -> anyhow::Result<()> {
    std::fs::create_dir_all(dir)
        .with_context(|| format!("cannot create run folder {}", dir.display()))?;
    let path = dir.join(SCENARIO_FILE);
    let text = toml::to_string(scenario).context("cannot write the scenario as TOML")?;
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))
}

/// The conventional output folder for a run: `DIR/<task>-<policy>-seed<N>`.
pub fn run_dir(root: &Path, task: TaskKind, policy: &str, seed: u64) -> PathBuf {
    root.join(format!("{task}-{policy}-seed{seed}"))
}
