//! The summary of one run: terminal and best errors, success, evaluations used, modelled
//! wall-clock time, error traces and (relay) milestones.

use serde::{Deserialize, Serialize};

use super::transcript::StepRecord;
use crate::rig::Score;
use crate::task::relay::milestones;
use crate::task::{TaskKind, TaskLimits};

/// What one run achieved, judged from the hidden truth.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    pub task: TaskKind,
    pub policy: String,
    pub seed: u64,
    pub budget: usize,
    pub evaluations_used: usize,
    pub rejected_actions: usize,
    /// The agent said done (never used to judge success).
    pub declared_done: bool,
    pub success: bool,
    /// Error of the final state (Michelson px, cavity steps, relay px at C8; `None` when
    /// the relay ends dark).
    pub terminal_error: Option<f64>,
    pub best_error: Option<f64>,
    /// Michelson only: the paper's error from commanded positions.
    pub terminal_commanded_error: Option<f64>,
    /// Error after each evaluation, index 0 = start.
    pub error_trace: Vec<Option<f64>>,
    /// Best error so far after each evaluation.
    pub best_trace: Vec<Option<f64>>,
    /// Relay only: evaluation from which each mirror stayed aligned.
    pub milestones: Option<[Option<usize>; 4]>,
    /// Modelled wall-clock, s.
    pub motor_time_s: f64,
    pub camera_time_s: f64,
    pub agent_time_s: f64,
    pub wall_clock_s: f64,
    /// Why the run ended early, if it did: it failed to run to its end (a run that spent
    /// its budget or was declared done without aligning has none).
    pub failure: Option<String>,
    /// What ended it early: the rig (camera, controller or camera mover), the policy (a
    /// model included), too many rejected actions, or the operator.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ended_by: Option<EndedBy>,
}

/// What ended a run before it was done or out of budget.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum EndedBy {
    /// The rig failed: its camera, a controller, or the camera mover.
    Rig,
    /// The policy could not decide (a model that failed or kept replying unusably).
    Policy,
    /// The policy kept sending actions the task refused.
    Rejections,
    /// The operator stopped the run.
    Operator,
}

/// Why a run ended early, and what ended it.
#[derive(Clone, Debug, PartialEq)]
pub struct Failure {
    pub by: EndedBy,
    pub reason: String,
}

/// Best (lowest) error among the scores so far.
pub fn best_error(scores: &[Score]) -> Option<f64> {
    scores
        .iter()
        .filter_map(Score::error)
        .min_by(f64::total_cmp)
}

/// Whether a state counts as aligned under the task's success rule.
pub fn is_success(score: &Score, limits: &TaskLimits) -> bool {
    match score {
        Score::Michelson(score) => score.error_px <= limits.michelson.success_error_px,
        Score::Cavity(score) => score.success,
        Score::Relay(score) => score.through_all_mirrors && score.aligned[3],
    }
}

/// Builds the summary from the per-evaluation scores (index 0 = start) and the steps.
#[allow(clippy::too_many_arguments)]
pub fn summarize(
    task: TaskKind,
    policy: &str,
    seed: u64,
    limits: &TaskLimits,
    scores: &[Score],
    records: &[StepRecord],
    declared_done: bool,
    failure: Option<Failure>,
) -> RunSummary {
    let error_trace: Vec<Option<f64>> = scores.iter().map(Score::error).collect();
    let best_trace: Vec<Option<f64>> = (1..=scores.len())
        .map(|n| best_error(&scores[..n]))
        .collect();
    let last = scores.last();
    let success = last.is_some_and(|score| is_success(score, limits));
    let relay_history: Vec<[bool; 4]> = scores
        .iter()
        .filter_map(|score| match score {
            Score::Relay(relay) => Some(relay.aligned),
            _ => None,
        })
        .collect();
    let executed = records.iter().filter(|r| r.rejected.is_none());
    let motor_time_s: f64 = executed.clone().map(|r| r.motor_time_s).sum();
    let camera_time_s: f64 = executed.map(|r| r.camera_time_s).sum();
    let agent_time_s: f64 = records.iter().map(|r| r.agent_latency_s).sum();
    RunSummary {
        task,
        policy: policy.to_owned(),
        seed,
        budget: limits.budget(task),
        evaluations_used: scores.len().saturating_sub(1),
        rejected_actions: records.iter().filter(|r| r.rejected.is_some()).count(),
        declared_done,
        success,
        terminal_error: last.and_then(Score::error),
        best_error: best_error(scores),
        terminal_commanded_error: match last {
            Some(Score::Michelson(score)) => Some(score.commanded_error_px),
            _ => None,
        },
        error_trace,
        best_trace,
        milestones: (task == TaskKind::Relay).then(|| milestones(&relay_history)),
        motor_time_s,
        camera_time_s,
        agent_time_s,
        wall_clock_s: motor_time_s + camera_time_s + agent_time_s,
        ended_by: failure.as_ref().map(|f| f.by),
        failure: failure.map(|f| f.reason),
    }
}
