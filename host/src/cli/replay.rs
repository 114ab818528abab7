//! `optalign replay`: re-runs a recorded VLM run against the simulator without calling a
//! model. The run's header gives the task and seed, its `scenario.toml` the scene, and the
//! decisions' claims every model answer in order; the answers go through the same parser
//! and corrective rounds as live, and the replay checks that every step (action, refusal,
//! timing and hidden-truth score) and the summary come out the same.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use serde_json::Value;

use crate::policy::TaskBrief;
use crate::policy::vlm::replay::{ReplayBackend, recorded_completions, recorded_options};
use crate::policy::vlm::{VlmOptions, VlmPolicy};
use crate::rig::{MotorPath, SimRig};
use crate::run::{RunOptions, RunSummary, StepRecord, run_episode};
use crate::run::{SCENARIO_FILE, record_scenario};
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The recorded run's folder (holding transcript.jsonl).
    dir: PathBuf,
    /// Where the replay writes its own transcript; default DIR/replay.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
}

/// A transcript read back.
struct Recorded {
    task: TaskKind,
    policy: String,
    seed: u64,
    steps: Vec<StepRecord>,
    summary: Option<RunSummary>,
}

/// Reads `transcript.jsonl`. A final line cut short by a killed run is skipped.
fn read_transcript(dir: &Path) -> anyhow::Result<Recorded> {
    let path = dir.join("transcript.jsonl");
    let text = std::fs::read_to_string(&path)
        .with_context(|| format!("cannot read {}", path.display()))?;
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut header = None;
    let mut steps = Vec::new();
    let mut summary = None;
    for (n, line) in lines.iter().enumerate() {
        let value: Value = match serde_json::from_str(line) {
            Ok(value) => value,
            Err(_) if n + 1 == lines.len() && !text.ends_with('\n') => {
                eprintln!("note: the last transcript line is incomplete (a killed run); skipped");
                break;
            }
            Err(error) => anyhow::bail!("{} line {}: {error}", path.display(), n + 1),
        };
        let context = || format!("{} line {}", path.display(), n + 1);
        match value["type"].as_str() {
            Some("run") => header = Some(value),
            Some("step") => steps.push(serde_json::from_value(value).with_context(context)?),
            Some("end") => summary = Some(serde_json::from_value(value).with_context(context)?),
            _ => {}
        }
    }
    let header = header.with_context(|| format!("{} has no run header", path.display()))?;
    Ok(Recorded {
        task: serde_json::from_value(header["task"].clone())
            .with_context(|| format!("{}: the header names no task", path.display()))?,
        policy: header["policy"].as_str().unwrap_or_default().to_owned(),
        seed: header["seed"]
            .as_u64()
            .with_context(|| format!("{}: the header names no seed", path.display()))?,
        steps,
        summary,
    })
}

/// A step without the agent's claims (whose request records name the endpoint).
fn trajectory(step: &StepRecord) -> anyhow::Result<Value> {
    let mut value = serde_json::to_value(step)?;
    if let Some(object) = value.as_object_mut() {
        object.remove("claims");
    }
    Ok(value)
}

fn describe(step: &StepRecord) -> String {
    format!(
        "{}{}, error {}",
        step.action.describe(),
        step.rejected
            .as_deref()
            .map(|r| format!(" (refused: {r})"))
            .unwrap_or_default(),
        step.error.map_or("n/a".into(), |e| format!("{e}"))
    )
}

/// Where a replayed trajectory first departs from the recorded one.
fn first_difference(
    recorded: &[StepRecord],
    replayed: &[StepRecord],
) -> anyhow::Result<Option<String>> {
    for (n, (a, b)) in recorded.iter().zip(replayed).enumerate() {
        if trajectory(a)? != trajectory(b)? {
            return Ok(Some(format!(
                "step {}: recorded {}; replayed {}",
                n + 1,
                describe(a),
                describe(b)
            )));
        }
    }
    Ok((recorded.len() != replayed.len()).then(|| {
        format!(
            "the recording has {} steps, the replay {}",
            recorded.len(),
            replayed.len()
        )
    }))
}

/// A summary without the failure text (a replay that runs out of answers fails in its own
/// words).
fn outcome(summary: &RunSummary) -> anyhow::Result<Value> {
    let mut value = serde_json::to_value(summary)?;
    if let Some(object) = value.as_object_mut() {
        object.remove("failure");
    }
    Ok(value)
}

pub async fn run(args: ReplayArgs) -> anyhow::Result<()> {
    let recorded = read_transcript(&args.dir)?;
    anyhow::ensure!(
        recorded.policy == "vlm",
        "{} is a run of the {:?} policy; replay re-runs vlm runs only",
        args.dir.display(),
        recorded.policy
    );
    let scenario_path = args.dir.join(SCENARIO_FILE);
    let scenario = if scenario_path.exists() {
        ScenarioFile::load(&scenario_path)?
    } else {
        eprintln!(
            "note: {} is missing; replaying on the default scenario",
            scenario_path.display()
        );
        ScenarioFile::default()
    };
    let mut completions = Vec::new();
    let mut options = None;
    for step in &recorded.steps {
        if let Some(claims) = &step.claims {
            completions.extend(recorded_completions(claims)?);
            options = options.or_else(|| recorded_options(claims));
        }
    }
    let mut options = options.unwrap_or_else(|| VlmOptions::new("replay"));
    // The prompt does not affect a replay, and its file may be gone.
    options.prompt = None;
    let brief = TaskBrief::new(
        recorded.task,
        &scenario.tasks,
        scenario.geometry(recorded.task),
    );
    let answers = completions.len();
    let mut policy =
        VlmPolicy::with_backend(&brief, &options, Box::new(ReplayBackend::new(completions)))?;
    let out = args.out.unwrap_or_else(|| args.dir.join("replay"));
    record_scenario(&out, &scenario)?;
    let mut rig = SimRig::new(
        recorded.task,
        &scenario,
        recorded.seed,
        MotorPath::InProcess,
    )
    .await?;
    let run_options = RunOptions {
        out_dir: Some(out.clone()),
        seed: recorded.seed,
        ..RunOptions::default()
    };
    let summary = run_episode(&mut rig, &mut policy, None, &scenario.tasks, &run_options).await?;
    let replayed = read_transcript(&out)?;
    crate::say!(
        "replayed {} recorded steps ({answers} model answers) of {} seed {} without calling a model; records in {}",
        recorded.steps.len(),
        recorded.task,
        recorded.seed,
        out.display()
    );
    if let Some(difference) = first_difference(&recorded.steps, &replayed.steps)? {
        anyhow::bail!("the replay departs from the recording at {difference}");
    }
    // Both summaries as read back from their transcripts, so both went through the same
    // decimal rendering.
    if let (Some(original), Some(replayed)) = (&recorded.summary, &replayed.summary) {
        anyhow::ensure!(
            outcome(original)? == outcome(replayed)?,
            "the steps match but the summaries differ: recorded terminal error {:?}, replayed {:?}",
            original.terminal_error,
            summary.terminal_error
        );
    }
    crate::say!(
        "trajectory and score reproduced exactly: {} evaluations, terminal error {}, {}",
        summary.evaluations_used,
        summary
            .terminal_error
            .map_or("n/a".into(), |e| format!("{e:.1}")),
        if summary.success {
            "success"
        } else {
            "not aligned"
        }
    );
    if recorded.summary.is_none() {
        crate::say!(
            "the recording ended without a summary (the run was interrupted); the replay stopped where it ends"
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_recorded_scenario_reads_back_unchanged() {
        let dir = tempfile::tempdir().unwrap();
        let mut scenario = ScenarioFile::default();
        scenario.cavity.ghosts.pop();
        scenario.tasks.relay.max_step = 9000;
        scenario.michelson.fringe_angle_deg = 12.345_678_9;
        record_scenario(dir.path(), &scenario).unwrap();
        assert_eq!(
            ScenarioFile::load(&dir.path().join(SCENARIO_FILE)).unwrap(),
            scenario
        );
    }
}
