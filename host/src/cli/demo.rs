//! `optalign demo`: our vision agent against the classical baselines on the three tasks, a
//! few seeds each, on simulated rigs driven through the simulated firmware peer over
//! loopback TCP (the full protocol path). A small bench: it prints each task's table, and
//! writes the speed-against-accuracy and convergence charts and an HTML report with every
//! run's error curve, and the filmstrips of the first seed's runs of the policies asked for.
//! No hardware, no API key.

use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;

use super::bench::{SeedList, parse_seed_list, resolve_policies, runs_progress};
use crate::bench::report::write_report;
use crate::bench::{BenchPlan, MatrixOptions, SavedFrames, default_jobs, run_bench};
use crate::rig::MotorPath;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

#[derive(Debug, Args)]
pub struct DemoArgs {
    /// Policies compared, comma-separated [default: random,bo,vision]; `vlm` needs a
    /// model: run it with `optalign bench --policies vlm --model ...`.
    #[arg(long, value_delimiter = ',')]
    policies: Vec<String>,
    /// Seeds (the hidden initial misalignments): a range 0..3 (half-open), a list 0,4,7,
    /// or one number.
    #[arg(long, default_value = "0..3", value_parser = parse_seed_list)]
    seeds: SeedList,
    /// Policies whose runs on the first seed keep their frames and show them as a
    /// filmstrip in the report, comma-separated (a frame is about 1 MB: a baseline's run
    /// of 60 evaluations keeps 60 MB).
    #[arg(long, value_delimiter = ',', default_value = "vision")]
    filmstrips: Vec<String>,
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
    let scenario = ScenarioFile::load_or_default(args.scenario.as_deref())?;
    let policies = resolve_policies(&args.policies)?;
    anyhow::ensure!(
        !policies.iter().any(|p| p == "vlm"),
        "the demo runs without an API key: compare the vlm policy with \
         `optalign bench --policies vlm,vision --model NAME` instead"
    );
    let seeds = args.seeds.0;
    for policy in &args.filmstrips {
        anyhow::ensure!(
            policies.contains(policy),
            "--filmstrips names {policy:?}, which the demo does not run (policies: {})",
            policies.join(", ")
        );
    }
    let saved_frames = SavedFrames::Only {
        policies: args.filmstrips,
        seeds: seeds.first().copied().into_iter().collect(),
    };
    let runs = TaskKind::ALL.len() * policies.len() * seeds.len();
    eprintln!(
        "demo: {} on the three tasks, {} seed(s) each ({runs} runs), motors over {}",
        policies.join(", "),
        seeds.len(),
        match args.motors {
            MotorPath::Peer => "the simulated firmware peer (loopback TCP)",
            MotorPath::InProcess => "the in-process firmware core",
        }
    );
    let plan = BenchPlan {
        tasks: TaskKind::ALL.to_vec(),
        policies,
        seeds,
        scenario: Arc::new(scenario),
        scenario_label: args
            .scenario
            .as_ref()
            .map_or_else(|| "defaults".to_owned(), |p| p.display().to_string()),
        out: args.out.clone(),
        options: MatrixOptions {
            jobs: default_jobs().min(runs),
            motors: args.motors,
            saved_frames,
            vlm: None,
            monitor: None,
            resume: false,
        },
        sweeps: Vec::new(),
    };
    let progress = runs_progress()?;
    let (output, report) = tokio::task::spawn_blocking(move || {
        let output = run_bench(&plan, &progress)?;
        let intro = format!(
            "{} on the three simulated tasks, seeds {:?}: the rigs run the firmware core \
             behind the simulated peer, and every image, action and score is in each run's \
             transcript. The charts set each policy's accuracy against the evaluations it \
             spent.",
            plan.policies.join(", "),
            plan.seeds
        );
        let report = write_report(
            &plan.out,
            "optalign demo: the vision agent and the baselines",
            &intro,
            &output.records,
            &output.charts,
        )?;
        anyhow::Ok((output, report))
    })
    .await??;
    crate::say!("{}", output.tables.trim_end());
    crate::say!(
        "\n{} runs in {:.1} s",
        output.records.len(),
        output.wall_time_s
    );
    crate::say!("output:  {}", args.out.display());
    crate::say!("report:  {}", report.display());
    crate::say!("summary: {}", output.summary.display());
    crate::say!(
        "charts:  {} files in {}",
        output.charts.len(),
        args.out.join("charts").display()
    );
    Ok(())
}
