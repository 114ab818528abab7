//! `optalign demo`: the three tasks with one policy (our vision agent by default) on
//! simulated rigs driven through the simulated firmware peer over loopback TCP, the full
//! protocol path. Prints a short table and writes charts and an HTML report with each
//! run's filmstrip. No hardware, no API key.

use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;
use indicatif::ProgressBar;

use crate::bench::charts::{error_unit, write_bench_charts};
use crate::bench::report::write_report;
use crate::bench::{MatrixOptions, default_jobs, matrix, run_matrix};
use crate::rig::MotorPath;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Who aligns.
    #[arg(long, default_value = "vision")]
    policy: String,
    /// Seed number: selects the hidden initial misalignments.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Scenario file (TOML); defaults apply when omitted.
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "runs/demo")]
    out: PathBuf,
    /// How motor commands reach the simulated firmware.
    #[arg(long, value_enum, default_value = "peer")]
    motors: MotorPath,
}

pub async fn run(args: DemoArgs) -> anyhow::Result<()> {
    let scenario = Arc::new(ScenarioFile::load_or_default(args.scenario.as_deref())?);
    let policies = vec![args.policy.clone()];
    let specs = matrix(
        &TaskKind::ALL,
        &policies,
        &[args.seed],
        &scenario,
        None,
        Some(&args.out),
    );
    let options = MatrixOptions {
        jobs: default_jobs().min(specs.len()),
        motors: args.motors,
        save_frames: true,
        vlm: None,
        monitor: None,
        resume: false,
    };
    eprintln!(
        "demo: {} on the three tasks, seed {}, motors over {}",
        args.policy,
        args.seed,
        match args.motors {
            MotorPath::Peer => "the simulated firmware peer (loopback TCP)",
            MotorPath::InProcess => "the in-process firmware core",
        }
    );
    let out = args.out.clone();
    let policy = args.policy.clone();
    let (records, report, charts) = tokio::task::spawn_blocking(move || {
        let records = run_matrix(&specs, &options, &ProgressBar::hidden())?;
        let charts = write_bench_charts(
            &out.join("charts"),
            &records,
            &TaskKind::ALL,
            &policies,
            &scenario,
        )?;
        let intro = format!(
            "{policy} on the three simulated tasks, seed {}: the rigs run the firmware core \
             behind the simulated peer, and every image, action and score is in each run's \
             transcript.",
            args.seed
        );
        // Each run's own error curve is in its section; of the matrix charts only the
        // relay milestones add to a one-seed report.
        let milestones: Vec<PathBuf> = charts
            .iter()
            .filter(|c| c.file_stem().is_some_and(|s| s == "relay_milestones"))
            .cloned()
            .collect();
        let report = write_report(
            &out,
            &format!("optalign demo: {policy}"),
            &intro,
            &records,
            &milestones,
        )?;
        anyhow::Ok((records, report, charts))
    })
    .await??;
    crate::say!("task       success  terminal error               evaluations");
    for record in &records {
        let s = &record.summary;
        let error = s.terminal_error.map_or_else(
            || "none (no light at C8)".to_owned(),
            |e| format!("{e:.1} {}", error_unit(s.task)),
        );
        crate::say!(
            "{:<10} {:<8} {:<28} {}/{}{}",
            s.task.name(),
            if s.success { "yes" } else { "no" },
            error,
            s.evaluations_used,
            s.budget,
            s.failure
                .as_deref()
                .map(|f| format!("  (ended early: {f})"))
                .unwrap_or_default()
        );
    }
    crate::say!("\noutput: {}", args.out.display());
    crate::say!("report: {}", report.display());
    crate::say!(
        "charts: {} files in {}",
        charts.len(),
        args.out.join("charts").display()
    );
    Ok(())
}
