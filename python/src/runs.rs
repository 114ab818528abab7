//! Whole runs and benches from Python: the same [`run_one`] and [`run_matrix`] as
//! `optalign run --sim` and `optalign bench`, returning the run summary and one row per run
//! (the columns of `results.csv`) as JSON for the Python side to decode.

use std::path::PathBuf;
use std::sync::Arc;

use indicatif::ProgressBar;
use optalign::bench::{
    MatrixOptions, RunRecord, RunSpec, SavedFrames, matrix, run_matrix, run_one,
};
use pyo3::prelude::*;
use serde_json::json;

use crate::errors::{failed, invalid};
use crate::runtime;
use crate::stepper::{load_scenario, parse_motors, parse_task};

/// The row of one run: the columns of `results.csv`, in its order.
fn row(record: &RunRecord) -> Vec<(&'static str, serde_json::Value)> {
    let summary = &record.summary;
    let milestone = |m: usize| json!(summary.milestones.and_then(|all| all[m]));
    vec![
        ("task", json!(summary.task)),
        ("policy", json!(summary.policy)),
        ("seed", json!(summary.seed)),
        ("success", json!(summary.success)),
        ("declared_done", json!(summary.declared_done)),
        ("terminal_error", json!(summary.terminal_error)),
        ("best_error", json!(summary.best_error)),
        ("evaluations_used", json!(summary.evaluations_used)),
        ("budget", json!(summary.budget)),
        ("rejected_actions", json!(summary.rejected_actions)),
        ("motor_time_s", json!(summary.motor_time_s)),
        ("camera_time_s", json!(summary.camera_time_s)),
        ("agent_time_s", json!(summary.agent_time_s)),
        ("wall_clock_s", json!(summary.wall_clock_s)),
        ("milestone_m1", milestone(0)),
        ("milestone_m2", milestone(1)),
        ("milestone_m3", milestone(2)),
        ("milestone_m4", milestone(3)),
        ("elapsed_s", json!(record.elapsed_s)),
        ("failure", json!(summary.failure)),
    ]
}

/// The policies a run from Python can use.
const POLICIES: [&str; 4] = ["vision", "bo", "random", "manual"];

/// Refuses a policy Python cannot run, saying which it can.
pub fn check_policy(name: &str) -> PyResult<()> {
    match name {
        _ if POLICIES.contains(&name) => Ok(()),
        "vlm" => Err(invalid(
            "the vlm policy needs the command line's model settings: run it with `optalign run --policy vlm --model ...`",
        )),
        _ => Err(invalid(format!(
            "unknown policy {name:?}: use {}",
            POLICIES.join(", ")
        ))),
    }
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
    check_policy(policy)?;
    let spec = RunSpec {
        task: parse_task(task).map_err(invalid)?,
        policy: policy.to_owned(),
        seed,
        scenario: Arc::new(load_scenario(scenario).map_err(invalid)?),
        setting: None,
        out_dir: out.clone(),
    };
    let options = MatrixOptions {
        jobs: 1,
        motors: parse_motors(motors).map_err(invalid)?,
        saved_frames: if out.is_some() {
            SavedFrames::All
        } else {
            SavedFrames::None
        },
        ..MatrixOptions::default()
    };
    let runtime = runtime::single_threaded()?;
    let record = py
        .detach(|| runtime.block_on(run_one(&spec, &options)))
        .map_err(failed)?;
    serde_json::to_string(&record.summary).map_err(invalid)
}

/// A task x policy x seed matrix on `jobs` threads; returns JSON `{"columns": [..],
/// "rows": [[..], ..]}`, one row per run in the matrix's order.
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
        .map(|task| parse_task(task).map_err(invalid))
        .collect::<PyResult<Vec<_>>>()?;
    if tasks.is_empty() || policies.is_empty() {
        return Err(invalid("a bench needs at least one task and one policy"));
    }
    optalign::bench::check_seeds(&seeds).map_err(|error| invalid(format!("seeds: {error}")))?;
    for policy in &policies {
        check_policy(policy)?;
    }
    let scenario = Arc::new(load_scenario(scenario).map_err(invalid)?);
    let specs = matrix(&tasks, &policies, &seeds, &scenario, None, None);
    let options = MatrixOptions {
        jobs: jobs.unwrap_or_else(optalign::bench::default_jobs),
        motors: parse_motors(motors).map_err(invalid)?,
        ..MatrixOptions::default()
    };
    let cores = optalign::bench::default_jobs();
    if !(1..=cores).contains(&options.jobs) {
        return Err(invalid(format!(
            "jobs must be from 1 to {cores} (the cores), not {}",
            options.jobs
        )));
    }
    let records = py
        .detach(|| run_matrix(&specs, &options, &ProgressBar::hidden()))
        .map_err(failed)?;
    let rows: Vec<_> = records.iter().map(row).collect();
    let columns: Vec<&str> = rows
        .first()
        .map(|first| first.iter().map(|(name, _)| *name).collect())
        .unwrap_or_default();
    let values: Vec<Vec<serde_json::Value>> = rows
        .into_iter()
        .map(|row| row.into_iter().map(|(_, value)| value).collect())
        .collect();
    serde_json::to_string(&json!({ "columns": columns, "rows": values })).map_err(invalid)
}
