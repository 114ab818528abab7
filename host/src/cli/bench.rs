//! `optalign bench`: the task x policy x seed matrix on simulated rigs, in parallel, with
//! `results.csv`, `summary.md`, charts and per-run transcripts; `--sweep KNOB=v1,v2,...`
//! (repeatable, or `all`) repeats it across the values of difficulty knobs and draws the
//! stability map.

use std::path::PathBuf;
use std::sync::Arc;

use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};

use super::monitor::MonitorArgs;
use super::run::VlmArgs;
use crate::bench::{
    BenchPlan, MatrixOptions, SavedFrames, SweepSpec, default_jobs, parse_seeds, run_bench,
};
use crate::monitor::Hub;
use crate::policy::policy_names;
use crate::policy::vlm::{self, CostEstimate, VlmOptions};
use crate::rig::MotorPath;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// The policies a bench (and the demo) compares when none are named.
const DEFAULT_POLICIES: [&str; 3] = ["random", "bo", "vision"];

#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Tasks, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "michelson,cavity,relay")]
    tasks: Vec<TaskKind>,
    /// Policies, comma-separated [default: random,bo,vision].
    #[arg(long, value_delimiter = ',')]
    policies: Vec<String>,
    /// Seeds: a range 0..10 (half-open) or 3..=5, a list 0,4,7, or one number.
    #[arg(long, default_value = "0..10", value_parser = parse_seed_list)]
    seeds: SeedList,
    /// Scenario file (TOML); defaults apply when omitted.
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Output folder.
    #[arg(long, value_name = "DIR", default_value = "runs/bench")]
    out: PathBuf,
    /// Runs in parallel, at most the number of cores [default: the number of cores].
    #[arg(long, value_parser = parse_jobs)]
    jobs: Option<usize>,
    /// Vary a scenario knob, e.g. noise=0,5,10,20 or beam_profile=gaussian,tem01; KNOB
    /// alone runs its standard values, `all` every knob. Repeat for several knobs. Knobs:
    /// noise, backlash, offset_scale, artefact_brightness, placement_error,
    /// sensitivity_scale, cross_coupling, beam_profile, texture, flicker, jitter,
    /// hot_pixels, stray_spots, ambient, gradient, smear, camera_rotation, camera_flip,
    /// pitch_error, hysteresis, fringe_drift (docs/simulation.md).
    #[arg(long, value_name = "KNOB=V1,V2,...", value_parser = SweepSpec::parse_many)]
    sweep: Vec<Vec<SweepSpec>>,
    /// Save every frame of every run next to its transcript (slow, large).
    #[arg(long)]
    frames: bool,
    /// How motor commands reach the simulated firmware.
    #[arg(long, value_enum, default_value = "in-process")]
    motors: MotorPath,
    /// Start even when the estimated model cost of the vlm runs is large.
    #[arg(long)]
    yes: bool,
    /// Read back the runs an earlier bench finished in --out (a run folder holding its
    /// summary.json and this very scenario) instead of running them again: a stopped
    /// sweep picks up where it stopped. Their real time is left blank in results.csv.
    #[arg(long)]
    resume: bool,
    #[command(flatten)]
    monitor: MonitorArgs,
    #[command(flatten)]
    vlm: VlmArgs,
}

/// The progress bar of a matrix of runs (its length is set when the runs are planned).
pub(super) fn runs_progress() -> anyhow::Result<ProgressBar> {
    Ok(ProgressBar::new(0).with_style(
        ProgressStyle::with_template(
            "{bar:40.cyan/blue} {pos}/{len} runs  {elapsed_precise} (eta {eta})",
        )?
        .progress_chars("=> "),
    ))
}

/// Seeds as `--seeds` names them.
#[derive(Clone, Debug)]
pub(super) struct SeedList(pub(super) Vec<u64>);

pub(super) fn parse_seed_list(text: &str) -> Result<SeedList, String> {
    parse_seeds(text).map(SeedList)
}

fn parse_jobs(text: &str) -> Result<usize, String> {
    let cores = default_jobs();
    text.parse::<usize>()
        .ok()
        .filter(|jobs| (1..=cores).contains(jobs))
        .ok_or_else(|| format!("{text:?} is not a number of jobs from 1 to {cores} (the cores)"))
}

/// The policies to run: the named ones (each must exist), or the defaults that exist.
pub(super) fn resolve_policies(named: &[String]) -> anyhow::Result<Vec<String>> {
    let available = policy_names();
    if named.is_empty() {
        let (present, missing): (Vec<&str>, Vec<&str>) =
            DEFAULT_POLICIES.iter().partition(|p| available.contains(p));
        if !missing.is_empty() {
            eprintln!(
                "note: policies {} are not available in this build; running {}",
                missing.join(", "),
                present.join(", ")
            );
        }
        return Ok(present.into_iter().map(str::to_owned).collect());
    }
    for policy in named {
        anyhow::ensure!(
            available.contains(&policy.as_str()),
            "unknown policy {policy:?}: available: {}",
            available.join(", ")
        );
    }
    Ok(named.to_vec())
}

/// With `vlm` in the matrix: checks its settings and key, prints the estimated model use of
/// all its runs, and requires `--yes` when that is large.
async fn vlm_preflight(
    args: &VlmArgs,
    yes: bool,
    runs_per_task: u64,
    policies: &[String],
    tasks: &[TaskKind],
    scenario: &ScenarioFile,
) -> anyhow::Result<Option<VlmOptions>> {
    if !policies.iter().any(|p| p == "vlm") {
        return Ok(None);
    }
    let options = args
        .options()
        .ok_or_else(|| anyhow::anyhow!("--policies vlm needs --model"))?;
    vlm::preflight(&options)?;
    let pricing = vlm::fetch_pricing(&options).await.unwrap_or_else(|error| {
        let error = format!("{error:#}");
        eprintln!(
            "note: no model prices from the endpoint ({})",
            crate::console::escape_controls(&error)
        );
        None
    });
    let mut estimate = CostEstimate::default();
    for &task in tasks {
        estimate.add(
            &vlm::estimate_cost(task, scenario, &options, pricing.as_ref())?.times(runs_per_task),
        );
    }
    eprintln!("vlm model use if every run spends its whole budget: {estimate}");
    anyhow::ensure!(
        yes || !vlm::needs_confirmation(&estimate),
        "the vlm runs may be expensive ({estimate}); pass --yes to start anyway"
    );
    Ok(Some(options))
}

pub async fn run(args: BenchArgs) -> anyhow::Result<()> {
    let scenario = ScenarioFile::load_or_default(args.scenario.as_deref())?;
    let mut tasks = Vec::new();
    for task in args.tasks {
        if !tasks.contains(&task) {
            tasks.push(task);
        }
    }
    let policies = resolve_policies(&args.policies)?;
    let sweeps: Vec<SweepSpec> = args.sweep.into_iter().flatten().collect();
    let values: usize = sweeps.iter().map(|s| s.values.len()).sum();
    let runs_per_task = (args.seeds.0.len() * values.max(1)) as u64;
    let vlm = vlm_preflight(
        &args.vlm,
        args.yes,
        runs_per_task,
        &policies,
        &tasks,
        &scenario,
    )
    .await?;
    let hub = args.monitor.is_on().then(Hub::matrix);
    let _server = match &hub {
        Some(hub) => args.monitor.serve(hub).await?,
        None => None,
    };
    let plan = BenchPlan {
        tasks,
        policies,
        seeds: args.seeds.0,
        scenario: Arc::new(scenario),
        scenario_label: args
            .scenario
            .as_ref()
            .map_or_else(|| "defaults".to_owned(), |p| p.display().to_string()),
        out: args.out,
        options: MatrixOptions {
            jobs: args.jobs.unwrap_or_else(default_jobs),
            motors: args.motors,
            saved_frames: if args.frames {
                SavedFrames::All
            } else {
                SavedFrames::None
            },
            vlm: vlm.clone(),
            monitor: hub,
            resume: args.resume,
        },
        sweeps,
    };
    let progress = runs_progress()?;
    let output = tokio::task::spawn_blocking(move || {
        run_bench(&plan, &progress).map(|output| (plan, output))
    })
    .await??;
    let (plan, output) = output;
    crate::say!("{}", output.tables.trim_end());
    crate::say!(
        "\n{} runs in {:.1} s on {} job(s)",
        output.records.len(),
        output.wall_time_s,
        plan.options.jobs
    );
    if let Some(vlm) = &vlm {
        crate::say!("model usage: {}", vlm.usage.total());
    }
    crate::say!("results: {}", output.csv.display());
    crate::say!("summary: {}", output.summary.display());
    crate::say!(
        "charts:  {} files in {}",
        output.charts.len(),
        plan.out.join("charts").display()
    );
    Ok(())
}
