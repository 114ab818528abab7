//! The run loop: policy decides, the task validates, the rig executes, the next image goes
//! back to the policy; every evaluation is scored from the rig's state and appended to the
//! transcript before the next one, so a crash never loses the log.

mod summary;
mod transcript;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;

pub use summary::{RunSummary, is_success, summarize};
pub use transcript::{StepRecord, Transcript};

use crate::policy::{Feedback, Observation, Policy, PrivilegedObjective};
use crate::rig::{Rig, Score};
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
}

impl Default for RunOptions {
    fn default() -> Self {
        Self {
            out_dir: None,
            save_frames: true,
            max_consecutive_rejections: 10,
            seed: 0,
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
    let budget = limits.budget(task);
    let mut state = TaskState::new(task, limits);
    let mut transcript = match &options.out_dir {
        Some(dir) => Some(Transcript::create(
            dir,
            task,
            &policy.name(),
            options.seed,
            budget,
        )?),
        None => None,
    };
    let mut image = Arc::new(
        rig.initial_image()
            .await
            .context("the rig produced no first image")?,
    );
    let mut scores: Vec<Score> = vec![rig.score()];
    let mut records: Vec<StepRecord> = Vec::new();
    let mut image_path = save_frame(transcript.as_mut(), options, 0, &image)?;
    if let (Some(transcript), Some(score)) = (transcript.as_mut(), scores.last()) {
        transcript.start_state(score, image_path.as_deref())?;
    }
    if let (Some(objective), Some(score)) = (objective, scores.last()) {
        objective.publish(score.objective());
    }
    let mut feedback = Feedback::Start;
    let mut evaluations = 0usize;
    let mut consecutive_rejections = 0usize;
    let mut declared_done = false;
    let mut failure = None;
    while evaluations < budget {
        let observation = Observation {
            evaluations_used: evaluations,
            remaining: budget - evaluations,
            image: image.clone(),
            image_path: image_path.clone(),
            feedback: feedback.clone(),
        };
        let decision = match policy.decide(&observation).await {
            Ok(decision) => decision,
            Err(error) => {
                failure = Some(format!("policy failed: {error}"));
                break;
            }
        };
        if let Err(reason) = state.check(&decision.action) {
            consecutive_rejections += 1;
            let record = StepRecord::rejected(evaluations, &decision, &reason);
            if let Some(transcript) = transcript.as_mut() {
                transcript.append(&record)?;
            }
            records.push(record);
            feedback = Feedback::Rejected {
                action: decision.action,
                reason,
            };
            if consecutive_rejections >= options.max_consecutive_rejections {
                failure = Some(format!(
                    "the policy sent {consecutive_rejections} invalid actions in a row; the run was ended"
                ));
                break;
            }
            continue;
        }
        consecutive_rejections = 0;
        state.apply(&decision.action);
        let executed = rig
            .execute(&decision.action)
            .await
            .with_context(|| format!("executing {}", decision.action.describe()))?;
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
        records.push(record);
        image = Arc::new(executed.image);
        if decision.action.is_done() {
            declared_done = true;
            break;
        }
        feedback = Feedback::Executed {
            action: decision.action,
        };
    }
    let summary = summarize(
        task,
        &policy.name(),
        options.seed,
        limits,
        &scores,
        &records,
        declared_done,
        failure,
    );
    if let Some(transcript) = transcript.as_mut() {
        transcript.finish(&summary)?;
    }
    Ok(summary)
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

/// The conventional output folder for a run: `DIR/<task>-<policy>-seed<N>`.
pub fn run_dir(root: &Path, task: TaskKind, policy: &str, seed: u64) -> PathBuf {
    root.join(format!("{task}-{policy}-seed{seed}"))
}
