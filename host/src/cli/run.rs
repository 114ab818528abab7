//! `optalign run`: one alignment run of one task with one policy, on a simulated rig
//! (`--sim`) or a bench described by a rig file (`--rig`).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};

use clap::Args;

use super::monitor::MonitorArgs;
use super::rezero::{RezeroOptions, rezero_bench};
use crate::lab::{LabRig, RigFile, error_basis};
use crate::monitor::Hub;
use crate::policy::vlm::{self, ReasoningEffort, VlmOptions};
use crate::policy::{PolicyOptions, TaskBrief, build_policy};
use crate::rig::{MotorPath, Rig, SimRig};
use crate::run::{RunOptions, record_scenario, run_dir, run_episode};
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// The file in a run folder that records the scenario the run used (read by `replay`).

#[derive(Debug, Args)]
pub struct RunArgs {
    /// Which task.
    task: TaskKind,
    /// Who decides: manual = you, at a prompt; random and bo = the paper's baselines;
    /// vlm = a vision-language model over a chat API (needs --model).
    #[arg(long, default_value = "manual")]
    policy: String,
    /// Run on the simulated scene (no hardware).
    #[arg(long, required_unless_present = "rig", conflicts_with = "rig")]
    sim: bool,
    /// Run on the bench described by this rig file (controllers, camera, camera mover).
    #[arg(long, value_name = "FILE")]
    rig: Option<PathBuf>,
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
    #[command(flatten)]
    monitor: MonitorArgs,
    /// Hold the run before its first action until it is resumed (or stepped) from the
    /// monitor's page.
    #[arg(long, requires = "monitor")]
    paused: bool,
    /// On a bench: find axes whose position was lost (power cut mid-move) from the camera
    /// and declare them before the first evaluation, as `optalign rezero` does.
    #[arg(long, requires = "rig")]
    rezero: bool,
    #[command(flatten)]
    rezero_options: RezeroOptions,
    #[command(flatten)]
    vlm: VlmArgs,
}

/// Settings of the vision-language-model policy (`--policy vlm`).
#[derive(Debug, Args)]
#[command(next_help_heading = "Vision-language model (--policy vlm)")]
pub struct VlmArgs {
    /// Model id at the endpoint, e.g. openai/gpt-5.6-sol on OpenRouter.
    #[arg(long)]
    model: Option<String>,
    /// OpenAI-compatible base URL: OpenRouter, https://api.openai.com/v1, or a local
    /// server such as http://127.0.0.1:8000/v1 (vLLM) or http://127.0.0.1:11434/v1 (Ollama).
    #[arg(long, default_value = vlm::DEFAULT_BASE_URL)]
    base_url: String,
    /// Environment variable holding the API key (a loopback server may need none).
    #[arg(long, default_value = vlm::DEFAULT_API_KEY_ENV, value_name = "NAME")]
    api_key_env: String,
    /// Reasoning effort; "off" sends no reasoning setting at all.
    #[arg(long, value_enum, default_value = "high")]
    reasoning_effort: ReasoningEffort,
    /// Output-token limit per reply [default: 20000 for michelson and cavity, 12000 for relay].
    #[arg(long)]
    max_tokens: Option<u32>,
    /// Sampling temperature [default: the provider's].
    #[arg(long)]
    temperature: Option<f64>,
    /// Time allowed for one model request, s.
    #[arg(long, default_value_t = 300.0)]
    timeout_s: f64,
    /// Frames are downscaled so their longer side is at most this, px.
    #[arg(long, default_value_t = vlm::image::DEFAULT_MAX_SIDE)]
    max_image_side: u32,
    /// Send only the newest N images (for models with a small context) [default: all].
    #[arg(long, value_name = "N")]
    keep_images: Option<usize>,
    /// A system-prompt template replacing the built-in one ({{placeholders}} are filled
    /// from the scenario's bounds).
    #[arg(long, value_name = "FILE")]
    prompt: Option<PathBuf>,
}

impl VlmArgs {
    /// The VLM settings, when a model was named.
    pub fn options(&self) -> Option<VlmOptions> {
        let model = self.model.as_ref()?;
        Some(VlmOptions {
            model: model.clone(),
            base_url: self.base_url.clone(),
            api_key_env: self.api_key_env.clone(),
            reasoning_effort: self.reasoning_effort,
            max_tokens: self.max_tokens,
            temperature: self.temperature,
            timeout_s: self.timeout_s,
            max_image_side: self.max_image_side,
            keep_images: self.keep_images,
            prompt: self.prompt.clone(),
            ..VlmOptions::default()
        })
    }
}

/// Refuses to run a bench whose controllers lost positions, saying how to find them.
async fn refuse_lost(lab: &LabRig, rig_path: &Path) -> anyhow::Result<()> {
    let lost = lab.lost_axes().await?;
    if lost.is_empty() {
        return Ok(());
    }
    let names = crate::lab::rigfile::task_axis_names(lab.rig_file().task);
    anyhow::bail!(
        "the controllers lost the position of {} (a reset in the middle of a move); find them with `optalign rezero --rig {}`, or run with --rezero; nothing was moved",
        lost.iter()
            .map(|&a| names[a].as_str())
            .collect::<Vec<_>>()
            .join(", "),
        rig_path.display()
    )
}

pub async fn run(args: RunArgs) -> anyhow::Result<()> {
    let scenario = ScenarioFile::load_or_default(args.scenario.as_deref())?;
    let bench = args.rig.as_deref().map(RigFile::load).transpose()?;
    if let Some(bench) = &bench {
        anyhow::ensure!(
            bench.task == args.task,
            "the rig file is set up for the {} task, not {}",
            bench.task,
            args.task
        );
    }
    let limits = bench
        .as_ref()
        .map_or_else(|| scenario.tasks.clone(), |b| b.limits.clone());
    let geometry = bench
        .as_ref()
        .map_or_else(|| scenario.geometry(args.task), |b| b.geometry.clone());
    let brief = TaskBrief::new(args.task, &limits, geometry);
    let vlm = args.vlm.options();
    if vlm.is_some() && args.policy != "vlm" {
        anyhow::bail!("--model applies to --policy vlm only");
    }
    let mut built = build_policy(
        &args.policy,
        &brief,
        &PolicyOptions {
            seed: args.seed,
            vlm: vlm.clone(),
        },
    )?;
    if let Some(vlm) = &vlm {
        let estimate = vlm::estimate_cost(args.task, &scenario, vlm, None)?;
        eprintln!("model use if the whole budget is spent: {estimate}");
    }
    let out = args
        .out
        .unwrap_or_else(|| run_dir(&PathBuf::from("runs"), args.task, &args.policy, args.seed));
    record_scenario(&out, &scenario)?;
    let basis = bench.as_ref().map(error_basis);
    let mut rig: Box<dyn Rig> = match (bench, &args.rig) {
        (Some(bench), Some(rig_path)) => {
            let setup = args
                .rezero
                .then(|| args.rezero_options.setup(rig_path, &bench))
                .transpose()?;
            let mut lab = LabRig::connect(bench).await?;
            match setup {
                Some(setup) => rezero_bench(&mut lab, &setup).await?,
                None => refuse_lost(&lab, rig_path).await?,
            }
            Box::new(lab)
        }
        _ => Box::new(SimRig::new(args.task, &scenario, args.seed, args.motors).await?),
    };
    let run_monitor = args
        .monitor
        .run_monitor(&out.display().to_string(), args.paused);
    let server = match &run_monitor {
        Some(run_monitor) => {
            args.monitor
                .serve(&Hub::single(run_monitor.clone()))
                .await?
        }
        None => None,
    };
    let options = RunOptions {
        out_dir: Some(out.clone()),
        seed: args.seed,
        monitor: run_monitor,
        ..RunOptions::default()
    };
    eprintln!("run folder: {}", out.display());
    let summary = run_episode(
        rig.as_mut(),
        built.policy.as_mut(),
        built.objective.as_ref(),
        &limits,
        &options,
    )
    .await?;
    if let Some(server) = server {
        if std::io::stdin().is_terminal() {
            eprintln!(
                "the run is over; its page stays up at {} until you press Enter",
                server.url
            );
            tokio::task::spawn_blocking(|| std::io::stdin().read_line(&mut String::new()))
                .await??;
        }
        server.close().await;
    }
    match (&basis, &args.rig) {
        (Some(basis), Some(rig_path)) => {
            crate::say!(
                "{} on {}: {} after {} evaluations; error {} ({})",
                summary.task,
                rig_path.display(),
                if summary.success {
                    "aligned"
                } else {
                    "not aligned"
                },
                summary.evaluations_used,
                summary
                    .terminal_error
                    .map_or("n/a (no light at C8)".into(), |e| {
                        format!("{e:.1} {}", basis.unit)
                    }),
                basis.measured_from,
            );
            crate::say!("aligned means {}", basis.aligned_when);
        }
        _ => crate::say!(
            "{} seed {}: {} after {} evaluations, terminal error {}",
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
        ),
    }
    if let Some(vlm) = &vlm {
        crate::say!("model usage: {}", vlm.usage.total());
    }
    crate::say!("transcript: {}", out.join("transcript.jsonl").display());
    match summary.failure {
        Some(failure) => anyhow::bail!("the run did not run to its end: {failure}"),
        None => Ok(()),
    }
}
