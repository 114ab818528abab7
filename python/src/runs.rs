//! Whole runs and benches from Python: the same [`run_one`] and [`run_matrix`] as
//! `optalign run --sim` and `optalign bench`, returning the run summary and one row per run
//! (the columns of `results.csv`) as JSON for the Python side to decode.

use std::path::PathBuf;
use std::sync::Arc;

use indicatif::ProgressBar;
use optalign::bench::{MatrixOptions, RunRecord, RunSpec, matrix, run_matrix, run_one};
use pyo3::prelude::*;

use crate::episode::{load_scenario, parse_motors, parse_task};
use crate::errors::{failed, invalid};
use crate::runtime;

/// The row of one run, with the columns of `results.csv`.
fn row(record: &RunRecord) -> serde_json::Value {
    let summary = &record.summary;
    let milestone = |m: usize| summary.milestones.and_then(|all| all[m]);
    serde_json::json!({
        "task": summary.task,
        "policy": summary.policy,
        "seed": summary.seed,
        "success": summary.success,
        "declared_done": summary.declared_done,
        "terminal_error": summary.terminal_error,
        "best_error": summary.best_error,
        "evaluations_used": summary.evaluations_used,
        "budget": summary.budget,
        "rejected_actions": summary.rejected_actions,
        "motor_time_s": summary.motor_time_s,
        "camera_time_s": summary.camera_time_s,
        "agent_time_s": summary.agent_time_s,
        "wall_clock_s": summary.wall_clock_s,
        "milestone_m1": milestone(0),
        "milestone_m2": milestone(1),
        "milestone_m3": milestone(2),
        "milestone_m4": milestone(3),
        "elapsed_s": record.elapsed_s,
        "failure": summary.failure,
    })
}

/// One simulated run; returns its summary as JSON. With `out`, the transcript, frames and
/// summary go to that folder as with `optalign run`.
#[pyfunction]
#[pyo3(signature = (task, policy, seed, scenario=None, motors="in-process", out=None))]
pub fn run_json(
    py: Python<'_>,
    task: &str,
    policy: &str,
    seed: u64,
    scenario: Option<PathBuf>,
    motors: &str,
    out: Option<PathBuf>,
) -> PyResult<String> {
    let spec = RunSpec {
        task: parse_task(task)?,
        policy: policy.to_owned(),
        seed,
        scenario: Arc::new(load_scenario(scenario)?),
        setting: None,
        out_dir: out.clone(),
    };
    let options = MatrixOptions {
        jobs: 1,
        motors: parse_motors(motors)?,
        save_frames: out.is_some(),
        vlm: None,
    };
    let runtime = runtime::single_threaded()?;
    let record = py
        .detach(|| runtime.block_on(run_one(&spec, &options)))
        .map_err(failed)?;
    serde_json::to_string(&record.summary).map_err(invalid)
}

/// A task x policy x seed matrix on `jobs` threads; returns one row per run as JSON.
#[pyfunction]
#[pyo3(signature = (tasks, policies, seeds, scenario=None, motors="in-process", jobs=None))]
pub fn bench_json(
    py: Python<'_>,
    tasks: Vec<String>,
    policies: Vec<String>,
    seeds: Vec<u64>,
    scenario: Option<PathBuf>,
    motors: &str,
    jobs: Option<usize>,
) -> PyResult<String> {
    let tasks = tasks
        .iter()
        .map(|task| parse_task(task))
        .collect::<PyResult<Vec<_>>>()?;
    if tasks.is_empty() || policies.is_empty() || seeds.is_empty() {
        return Err(invalid(
            "a bench needs at least one task, one policy and one seed",
        ));
    }
    let scenario = Arc::new(load_scenario(scenario)?);
    let specs = matrix(&tasks, &policies, &seeds, &scenario, None, None);
    let options = MatrixOptions {
        jobs: jobs.unwrap_or_else(optalign::bench::default_jobs),
        motors: parse_motors(motors)?,
        ..MatrixOptions::default()
    };
    if options.jobs == 0 {
        return Err(invalid("jobs must be at least 1"));
    }
    let records = py
        .detach(|| run_matrix(&specs, &options, &ProgressBar::hidden()))
        .map_err(failed)?;
    serde_json::to_string(&records.iter().map(row).collect::<Vec<_>>()).map_err(invalid)
}
