//! `optalign run`: one alignment run of one task with one policy on a simulated rig.

use std::path::PathBuf;

use clap::Args;

use crate::policy::{PolicyOptions, TaskBrief, build_policy};
use crate::rig::{MotorPath, SimRig};
use crate::run::{RunOptions, run_dir, run_episode};
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Which task.
    task: TaskKind,
    /// Who decides (see `optalign run --help`): manual = you, at a prompt.
    #[arg(long, default_value = "manual")]
    policy: String,
    /// Run on the simulated scene (no hardware).
    #[arg(long, required = true)]
    sim: bool,
    /// Seed number: selects the hidden initial misalignment.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Scenario file (TOML); defaults apply when omitted.
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Output folder; default runs/<task>-<policy>-seed<N>.
    #[arg(long, value_name = "DIR")]
    out: Option<PathBuf>,
    /// How motor commands reach the simulated firmware.
    #[arg(long, value_enum, default_value = "in-process")]
    motors: MotorPath,
}

pub async fn run(args: RunArgs) -> anyhow::Result<()> {
    let scenario = ScenarioFile::load_or_default(args.scenario.as_deref())?;
    let brief = TaskBrief {
        task: args.task,
        limits: scenario.tasks.clone(),
        budget: scenario.tasks.budget(args.task),
    };
    let mut built = build_policy(&args.policy, &brief, &PolicyOptions { seed: args.seed })?;
    let out = args
        .out
        .unwrap_or_else(|| run_dir(&PathBuf::from("runs"), args.task, &args.policy, args.seed));
    let mut rig = SimRig::new(args.task, &scenario, args.seed, args.motors).await?;
    let options = RunOptions {
        out_dir: Some(out.clone()),
        seed: args.seed,
        ..RunOptions::default()
    };
    eprintln!("run folder: {}", out.display());
    let summary = run_episode(
        &mut rig,
        built.policy.as_mut(),
        built.objective.as_ref(),
        &scenario.tasks,
        &options,
    )
    .await?;
    println!(
        "{} seed {}: {} after {} evaluations, terminal error {}{}",
        summary.task,
        summary.seed,
        if summary.success {
            "success"
        } else {
            "not aligned"
        },
        summary.evaluations_used,
        summary
            .terminal_error
            .map_or("n/a (no light at C8)".into(), |e| format!("{e:.1}")),
        summary
            .failure
            .as_deref()
            .map(|f| format!(" ({f})"))
            .unwrap_or_default(),
    );
    println!("transcript: {}", out.join("transcript.jsonl").display());
    Ok(())
}
