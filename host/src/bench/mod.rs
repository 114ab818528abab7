//! The benchmark: runs a task x policy x seed matrix (optionally across the values of one
//! difficulty knob) on simulated rigs in parallel, then writes `results.csv`, `summary.md`
//! and the charts. Each worker thread drives its own rig and its own single-threaded async
//! runtime, so runs never share state.

pub mod charts;
pub mod report;
pub mod results;
pub mod resume;
pub mod sweep;

use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use anyhow::Context;
use indicatif::ProgressBar;

use crate::monitor::Hub;
use crate::policy::vlm::VlmOptions;
use crate::policy::{PolicyOptions, TaskBrief, build_policy};
use crate::rig::{MotorPath, SimRig};
use crate::run::{RunOptions, RunSummary, run_dir, run_episode};
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

pub use sweep::{Knob, Setting, SweepSpec};

/// One run of the matrix.
#[derive(Clone, Debug)]
pub struct RunSpec {
    pub task: TaskKind,
    pub policy: String,
    pub seed: u64,
    pub scenario: Arc<ScenarioFile>,
    /// The knob value this run belongs to, in a sweep.
    pub setting: Option<Setting>,
    /// Where its transcript goes; nothing is written when `None`.
    pub out_dir: Option<PathBuf>,
}

/// One finished run.
#[derive(Clone, Debug)]
pub struct RunRecord {
    pub summary: RunSummary,
    pub setting: Option<Setting>,
    pub out_dir: Option<PathBuf>,
    /// Real time the run took on this machine, s (`None`: read back from an earlier
    /// bench, see [`MatrixOptions::resume`]).
    pub elapsed_s: Option<f64>,
}

/// How the matrix runs.
#[derive(Clone, Debug)]
pub struct MatrixOptions {
    /// Worker threads.
    pub jobs: usize,
    pub motors: MotorPath,
    /// Which runs save every frame next to their transcript.
    pub saved_frames: SavedFrames,
    /// Settings of the `vlm` policy, when the matrix has it.
    pub vlm: Option<VlmOptions>,
    /// The live monitor showing the matrix, when one is served.
    pub monitor: Option<Hub>,
    /// Read back runs an earlier bench finished in the same folders (see [`resume`]).
    pub resume: bool,
}

impl Default for MatrixOptions {
    fn default() -> Self {
        Self {
            jobs: default_jobs(),
            motors: MotorPath::InProcess,
            saved_frames: SavedFrames::None,
            vlm: None,
            monitor: None,
            resume: false,
        }
    }
}

/// Which runs of a matrix keep their frames (a full-size frame is about 1 MB, so a
/// baseline's run of 60 evaluations about 60 MB).
#[derive(Clone, Debug, Default)]
pub enum SavedFrames {
    #[default]
    None,
    All,
    /// The runs of these policies on these seeds.
    Only {
        policies: Vec<String>,
        seeds: Vec<u64>,
    },
}

impl SavedFrames {
    /// Whether the run `spec` saves its frames.
    pub fn keeps(&self, spec: &RunSpec) -> bool {
        match self {
            Self::None => false,
            Self::All => true,
            Self::Only { policies, seeds } => {
                policies.contains(&spec.policy) && seeds.contains(&spec.seed)
            }
        }
    }
}

/// The number of cores this machine offers.
pub fn default_jobs() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The runs of a task x policy x seed matrix on one scenario; transcripts go under
/// `runs_root` (`<task>-<policy>-seed<N>`) when it is given.
pub fn matrix(
    tasks: &[TaskKind],
    policies: &[String],
    seeds: &[u64],
    scenario: &Arc<ScenarioFile>,
    setting: Option<Setting>,
    runs_root: Option<&std::path::Path>,
) -> Vec<RunSpec> {
    let mut specs = Vec::with_capacity(tasks.len() * policies.len() * seeds.len());
    for &task in tasks {
        for policy in policies {
            for &seed in seeds {
                specs.push(RunSpec {
                    task,
                    policy: policy.clone(),
                    seed,
                    scenario: scenario.clone(),
                    setting,
                    out_dir: runs_root.map(|root| run_dir(root, task, policy, seed)),
                });
            }
        }
    }
    specs
}

/// Runs every spec on `options.jobs` worker threads, advancing `progress` as runs finish;
/// the records come back in the specs' order. The first failing run (a rig or file error;
/// a policy that gives up only ends its own run) fails the whole matrix.
pub fn run_matrix(
    specs: &[RunSpec],
    options: &MatrixOptions,
    progress: &ProgressBar,
) -> anyhow::Result<Vec<RunRecord>> {
    let next = AtomicUsize::new(0);
    let slots: Mutex<Vec<Option<anyhow::Result<RunRecord>>>> =
        Mutex::new((0..specs.len()).map(|_| None).collect());
    std::thread::scope(|scope| {
        for _ in 0..options.jobs.clamp(1, specs.len().max(1)) {
            scope.spawn(|| {
                let runtime = tokio::runtime::Builder::new_current_thread()
                    .enable_all()
                    .build();
                loop {
                    let index = next.fetch_add(1, Ordering::Relaxed);
                    let Some(spec) = specs.get(index) else { break };
                    let record = match &runtime {
                        Ok(runtime) => runtime.block_on(run_one(spec, options)),
                        Err(error) => Err(anyhow::anyhow!("cannot start a runtime: {error}")),
                    };
                    progress.inc(1);
                    let record = record.with_context(|| {
                        format!("{} with {} on seed {}", spec.task, spec.policy, spec.seed)
                    });
                    slots.lock().unwrap_or_else(|e| e.into_inner())[index] = Some(record);
                }
            });
        }
    });
    slots
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|slot| slot.unwrap_or_else(|| Err(anyhow::anyhow!("a run never finished"))))
        .collect()
}

/// Runs one spec on its own simulated rig.
pub async fn run_one(spec: &RunSpec, options: &MatrixOptions) -> anyhow::Result<RunRecord> {
    if options.resume
        && let Some(summary) = spec
            .out_dir
            .as_deref()
            .and_then(|dir| resume::finished(spec, dir))
    {
        return Ok(RunRecord {
            summary,
            setting: spec.setting,
            out_dir: spec.out_dir.clone(),
            elapsed_s: None,
        });
    }
    let started = Instant::now();
    let scenario = spec.scenario.as_ref();
    let brief = TaskBrief::new(spec.task, &scenario.tasks, scenario.geometry(spec.task));
    let policy_options = PolicyOptions {
        seed: spec.seed,
        vlm: options.vlm.clone(),
    };
    let mut built = build_policy(&spec.policy, &brief, &policy_options)?;
    let mut rig = SimRig::new(spec.task, scenario, spec.seed, options.motors).await?;
    if let Some(dir) = &spec.out_dir {
        // The run can be repeated alone: `optalign run --scenario DIR/scenario.toml`.
        crate::run::record_scenario(dir, scenario)?;
    }
    let monitor = options.monitor.as_ref().map(|hub| {
        let setting = spec.setting.map(|s| format!(" at {s}")).unwrap_or_default();
        hub.add_run(&format!(
            "{} {} seed {}{setting}",
            spec.task, spec.policy, spec.seed
        ))
    });
    let run_options = RunOptions {
        out_dir: spec.out_dir.clone(),
        save_frames: options.saved_frames.keeps(spec),
        seed: spec.seed,
        monitor,
        ..RunOptions::default()
    };
    let summary = run_episode(
        &mut rig,
        built.policy.as_mut(),
        built.objective.as_ref(),
        &scenario.tasks,
        &run_options,
    )
    .await?;
    Ok(RunRecord {
        summary,
        setting: spec.setting,
        out_dir: spec.out_dir.clone(),
        elapsed_s: Some(started.elapsed().as_secs_f64()),
    })
}

/// A whole bench: the matrix, where it goes, and optionally one knob to sweep.
#[derive(Clone, Debug)]
pub struct BenchPlan {
    pub tasks: Vec<TaskKind>,
    pub policies: Vec<String>,
    pub seeds: Vec<u64>,
    pub scenario: Arc<ScenarioFile>,
    /// How the summary names the scenario (its file, or "defaults").
    pub scenario_label: String,
    pub out: PathBuf,
    pub options: MatrixOptions,
    /// Knobs to sweep, one after the other (none: the plain matrix).
    pub sweeps: Vec<SweepSpec>,
}

/// What a bench produced.
#[derive(Debug)]
pub struct BenchOutput {
    pub records: Vec<RunRecord>,
    pub csv: PathBuf,
    pub summary: PathBuf,
    pub charts: Vec<PathBuf>,
    /// The tables of `summary.md`, for printing.
    pub tables: String,
    pub wall_time_s: f64,
}

/// Runs a bench and writes `results.csv`, `summary.md`, `charts/` and the per-run
/// transcripts under `runs/` in the plan's output folder.
pub fn run_bench(plan: &BenchPlan, progress: &ProgressBar) -> anyhow::Result<BenchOutput> {
    let started = Instant::now();
    let runs_root = plan.out.join("runs");
    let (specs, tasks, settings) = if plan.sweeps.is_empty() {
        (
            matrix(
                &plan.tasks,
                &plan.policies,
                &plan.seeds,
                &plan.scenario,
                None,
                Some(&runs_root),
            ),
            plan.tasks.clone(),
            Vec::new(),
        )
    } else {
        sweep_matrix(plan, &runs_root)?
    };
    std::fs::create_dir_all(&plan.out)
        .with_context(|| format!("cannot create {}", plan.out.display()))?;
    progress.set_length(specs.len() as u64);
    if let Some(hub) = &plan.options.monitor {
        hub.set_planned(specs.len());
    }
    let records = run_matrix(&specs, &plan.options, progress)?;
    progress.finish_and_clear();
    let wall_time_s = started.elapsed().as_secs_f64();
    let charts_dir = plan.out.join("charts");
    let (tables, charts) = if settings.is_empty() {
        (
            results::task_tables(&records, &tasks, &plan.policies, &plan.scenario),
            charts::write_bench_charts(
                &charts_dir,
                &records,
                &tasks,
                &plan.policies,
                &plan.scenario,
            )?,
        )
    } else {
        (
            results::sweep_tables(&records, &tasks, &plan.policies, &settings),
            charts::write_sweep_charts(&charts_dir, &records, &tasks, &plan.policies, &settings)?,
        )
    };
    let csv = plan.out.join("results.csv");
    results::write_csv(&csv, &records)?;
    let summary = plan.out.join("summary.md");
    let info = results::BenchInfo {
        tasks,
        policies: plan.policies.clone(),
        seeds: plan.seeds.clone(),
        scenario: plan.scenario_label.clone(),
        jobs: plan.options.jobs,
        wall_time_s,
    };
    results::write_summary(&summary, &info, &tables, &charts)?;
    Ok(BenchOutput {
        records,
        csv,
        summary,
        charts,
        tables,
        wall_time_s,
    })
}

/// The runs of every sweep in the plan, with the tasks any knob applies to and every
/// knob value. A knob that changes none of the plan's tasks is an error when it is the only
/// one, and is skipped (with a note) among several.
fn sweep_matrix(
    plan: &BenchPlan,
    runs_root: &std::path::Path,
) -> anyhow::Result<(Vec<RunSpec>, Vec<TaskKind>, Vec<Setting>)> {
    let mut specs = Vec::new();
    let mut settings = Vec::new();
    let mut swept_tasks = Vec::new();
    for sweep in &plan.sweeps {
        let tasks: Vec<TaskKind> = plan
            .tasks
            .iter()
            .copied()
            .filter(|t| sweep.knob.applies_to(*t))
            .collect();
        if tasks.is_empty() {
            let names = plan.tasks.iter().map(|t| t.name()).collect::<Vec<_>>();
            anyhow::ensure!(
                plan.sweeps.len() > 1,
                "sweep knob {} changes none of the tasks {}",
                sweep.knob,
                names.join(", ")
            );
            eprintln!(
                "note: sweep knob {} changes none of {}; skipped",
                sweep.knob,
                names.join(", ")
            );
            continue;
        }
        for (setting, scenario) in sweep
            .scenarios(&plan.scenario)
            .map_err(anyhow::Error::msg)?
        {
            let root = runs_root.join(setting.to_string());
            specs.extend(matrix(
                &tasks,
                &plan.policies,
                &plan.seeds,
                &Arc::new(scenario),
                Some(setting),
                Some(&root),
            ));
            settings.push(setting);
        }
        for task in tasks {
            if !swept_tasks.contains(&task) {
                swept_tasks.push(task);
            }
        }
    }
    swept_tasks.sort_by_key(|t| plan.tasks.iter().position(|p| p == t));
    Ok((specs, swept_tasks, settings))
}

/// The most seeds one list may name (a bench keeps a record per run in memory).
pub const MAX_SEEDS: usize = 100_000;

/// Parses a seed list: `0..10` (half-open), `3..=5`, `0,4,7`, or one number; at most
/// [`MAX_SEEDS`] seeds, none named twice.
pub fn parse_seeds(text: &str) -> Result<Vec<u64>, String> {
    let number = |s: &str| {
        s.trim()
            .parse::<u64>()
            .map_err(|_| format!("{:?} is not a seed number", s.trim()))
    };
    let too_many = || format!("{text:?} names more than {MAX_SEEDS} seeds");
    let range = |from: u64, past: Option<u64>| -> Result<Vec<u64>, String> {
        let past = past.ok_or_else(too_many)?;
        if past.saturating_sub(from) > MAX_SEEDS as u64 {
            return Err(too_many());
        }
        Ok((from..past).collect())
    };
    let seeds: Vec<u64> = if let Some((from, to)) = text.split_once("..=") {
        range(number(from)?, number(to)?.checked_add(1))?
    } else if let Some((from, to)) = text.split_once("..") {
        range(number(from)?, Some(number(to)?))?
    } else {
        text.split(',').map(number).collect::<Result<_, _>>()?
    };
    check_seeds(&seeds).map_err(|error| format!("{text:?}: {error}"))?;
    Ok(seeds)
}

/// Checks a list of seeds: at least one, at most [`MAX_SEEDS`], none named twice (a seed
/// named twice would run twice into the same run folder).
pub fn check_seeds(seeds: &[u64]) -> Result<(), String> {
    if seeds.is_empty() {
        return Err("no seeds named".to_owned());
    }
    if seeds.len() > MAX_SEEDS {
        return Err(format!("more than {MAX_SEEDS} seeds"));
    }
    let mut seen = std::collections::HashSet::with_capacity(seeds.len());
    match seeds.iter().find(|&&seed| !seen.insert(seed)) {
        Some(repeated) => Err(format!(
            "seed {repeated} is named twice: each seed runs once"
        )),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seed_lists_parse_in_every_form() {
        assert_eq!(parse_seeds("0..10").unwrap(), (0..10).collect::<Vec<_>>());
        assert_eq!(parse_seeds("3..=5").unwrap(), vec![3, 4, 5]);
        assert_eq!(parse_seeds("0, 4,7").unwrap(), vec![0, 4, 7]);
        assert_eq!(parse_seeds("12").unwrap(), vec![12]);
        assert!(parse_seeds("5..5").unwrap_err().contains("no seeds named"));
        assert!(parse_seeds("a..3").unwrap_err().contains("\"a\""));
    }

    #[test]
    fn seed_lists_are_bounded_and_never_repeat() {
        for huge in [
            "0..18446744073709551615",
            "0..1000000000",
            "0..=18446744073709551615",
        ] {
            let error = parse_seeds(huge).unwrap_err();
            assert!(error.contains("more than"), "{huge}: {error}");
        }
        assert_eq!(
            parse_seeds(&format!("0..{MAX_SEEDS}")).unwrap().len(),
            MAX_SEEDS
        );
        let error = parse_seeds("0,0,0").unwrap_err();
        assert!(error.contains("seed 0 is named twice"), "{error}");
        assert!(parse_seeds("3, 4,3").unwrap_err().contains("seed 3"));
    }
}
