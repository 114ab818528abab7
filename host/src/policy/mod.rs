//! The policy interface: every decision-maker (a person, the baselines, our vision agent,
//! a vision-language model) sits behind [`Policy`]. A policy sees the task brief, then per
//! evaluation the new image and the feedback on its last action, and returns the next
//! action. Nothing outside a policy knows which policy runs.
//!
//! Privileged information, the scalar objective computed from the hidden state, reaches
//! only the baselines the paper gave it to, and only through [`PrivilegedObjective`], which
//! the run loop fills when (and only when) the policy's constructor asked for it.

pub mod bo;
mod factory;
pub mod manual;
pub mod random;
pub mod vision;
pub mod vlm;

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use async_trait::async_trait;
use optalign_optics::Frame;
use serde::{Deserialize, Serialize};

use crate::task::{Action, BenchGeometry, TaskKind, TaskLimits};

pub use factory::{BuiltPolicy, PolicyOptions, build_policy, policy_names};

/// What a policy is told before the first image.
#[derive(Clone, Debug)]
pub struct TaskBrief {
    pub task: TaskKind,
    /// Bounds and budgets of the tasks (the policy reads its own task's).
    pub limits: TaskLimits,
    pub budget: usize,
    /// What is known about the bench's geometry (from the rig file or the scenario).
    pub geometry: BenchGeometry,
}

impl TaskBrief {
    /// The brief for `task` under `limits`, with the task's own evaluation budget, on a
    /// bench of `geometry`.
    pub fn new(task: TaskKind, limits: &TaskLimits, geometry: BenchGeometry) -> Self {
        Self {
            task,
            limits: limits.clone(),
            budget: limits.budget(task),
            geometry,
        }
    }
}

/// What happened to the previous decision.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Feedback {
    /// The first image, before any action.
    Start,
    /// The action ran; the image shows its result.
    Executed { action: Action },
    /// The action was refused and nothing moved; the image is unchanged.
    Rejected { action: Action, reason: String },
}

/// One observation: the current image and the outcome of the last decision.
#[derive(Clone, Debug)]
pub struct Observation {
    /// Evaluations spent so far.
    pub evaluations_used: usize,
    /// Evaluations left in the budget.
    pub remaining: usize,
    pub image: Arc<Frame>,
    /// Where the run saved this image, when it saves images.
    pub image_path: Option<PathBuf>,
    pub feedback: Feedback,
}

/// A policy's answer.
#[derive(Clone, Debug)]
pub struct Decision {
    pub action: Action,
    /// What the agent claims about the scene (beam positions, visibility, reasoning), kept
    /// for analysis next to the hidden truth and never used for scoring.
    pub claims: Option<serde_json::Value>,
    /// Modelled time the policy took to decide, s (a model call's latency, say).
    pub latency_s: f64,
}

impl Decision {
    pub fn new(action: Action) -> Self {
        Self {
            action,
            claims: None,
            latency_s: 0.0,
        }
    }
}

/// Why a policy could not decide; ends the run (its transcript stays intact).
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct PolicyError {
    pub message: String,
    /// What the policy did before it gave up (a model's unusable replies, say), for the
    /// transcript: nothing the policy tried is lost with the run.
    pub record: Option<serde_json::Value>,
}

impl PolicyError {
    pub fn new(message: impl Into<String>) -> Self {
        Self {
            message: message.into(),
            record: None,
        }
    }

    /// The same error carrying `record` for the transcript.
    pub fn with_record(mut self, record: serde_json::Value) -> Self {
        self.record = Some(record);
        self
    }
}

/// A decision-maker.
#[async_trait]
pub trait Policy: Send {
    /// A short name for records and charts.
    fn name(&self) -> String;

    /// The next action for this observation.
    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError>;
}

/// The privileged scalar objective channel: the run loop writes the objective of the
/// state after each evaluation; a baseline reads it. Only policies constructed with one
/// ever see a value.
#[derive(Clone, Debug, Default)]
pub struct PrivilegedObjective(Arc<Mutex<Option<f64>>>);

impl PrivilegedObjective {
    /// The objective of the current state (to maximise), when the run has published one.
    pub fn read(&self) -> Option<f64> {
        *self.0.lock().unwrap_or_else(|e| e.into_inner())
    }

    pub(crate) fn publish(&self, objective: f64) {
        *self.0.lock().unwrap_or_else(|e| e.into_inner()) = Some(objective);
    }
}
