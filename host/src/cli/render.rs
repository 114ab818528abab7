//! `optalign render`: one camera frame of a simulated scene, for looking at a state by eye.

use std::path::PathBuf;

use anyhow::{Context, bail};
use clap::Args;
use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{CameraPose, Cavity, Michelson, Relay, Station};

use crate::scenario::ScenarioFile;
use crate::task::{TaskKind, cavity, michelson};

#[derive(Debug, Args)]
pub struct RenderArgs {
    /// Which scene.
    task: TaskKind,
    /// Seed number: selects the hidden initial misalignment.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Scenario file (TOML); defaults apply when omitted.
    #[arg(long, value_name = "FILE")]
    scenario: Option<PathBuf>,
    /// Motor settings relative to the start, AXIS=STEPS with an axis number or name
    /// (mirror_1_axis_1, x, m2v, ...). Unset axes stay at 0.
    #[arg(long = "set", value_name = "AXIS=STEPS", allow_negative_numbers = true)]
    settings: Vec<String>,
    /// Render the aligned state (every axis at the negative of its hidden offset).
    #[arg(long, conflicts_with = "settings")]
    aligned: bool,
    /// Relay camera station (C1..C8); default C8.
    #[arg(long, default_value = "C8")]
    station: Station,
    /// Output PNG.
    #[arg(long, value_name = "FILE")]
    out: PathBuf,
}

/// Axis names accepted by `--set`, per task, in axis order.
fn axis_names(task: TaskKind) -> Vec<String> {
    match task {
        TaskKind::Michelson => michelson::AXIS_NAMES
            .iter()
            .map(|s| s.to_string())
            .collect(),
        TaskKind::Cavity => cavity::AXIS_NAMES.iter().map(|s| s.to_string()).collect(),
        TaskKind::Relay => (1..=4)
            .flat_map(|m| [format!("m{m}v"), format!("m{m}h")])
            .collect(),
    }
}

fn parse_settings(task: TaskKind, settings: &[String]) -> anyhow::Result<Vec<i32>> {
    let names = axis_names(task);
    let mut shafts = vec![0; task.axes()];
    for setting in settings {
        let (axis, value) = setting
            .split_once('=')
            .with_context(|| format!("--set expects AXIS=STEPS, got {setting:?}"))?;
        let index = match axis.parse::<usize>() {
            Ok(index) if index < shafts.len() => index,
            Ok(index) => bail!(
                "--set {setting}: the {task} task has axes 0..={}, not {index}",
                shafts.len() - 1
            ),
            Err(_) => names
                .iter()
                .position(|name| name.eq_ignore_ascii_case(axis))
                .with_context(|| {
                    format!(
                        "--set {setting}: unknown axis {axis:?}; use 0..{} or one of {}",
                        shafts.len() - 1,
                        names.join(", ")
                    )
                })?,
        };
        shafts[index] = value.parse().with_context(|| {
            format!("--set {setting}: {value:?} is not a whole number of steps")
        })?;
    }
    Ok(shafts)
}

pub fn run(args: RenderArgs) -> anyhow::Result<()> {
    let scenario = ScenarioFile::load_or_default(args.scenario.as_deref())?;
    let settings = parse_settings(args.task, &args.settings)?;
    let frame = match args.task {
        TaskKind::Michelson => {
            let offsets = michelson_offsets(&scenario.michelson, args.seed);
            let shafts = if args.aligned {
                offsets.map(|o| -o).to_vec()
            } else {
                settings
            };
            Michelson::new(scenario.michelson.clone(), offsets)?.render(&shafts, 0)
        }
        TaskKind::Cavity => {
            let offsets = cavity_offsets(&scenario.cavity, args.seed);
            let shafts = if args.aligned {
                offsets.map(|o| -o).to_vec()
            } else {
                settings
            };
            Cavity::new(scenario.cavity.clone(), offsets)?.render(&shafts, 0)
        }
        TaskKind::Relay => {
            let offsets = relay_offsets(&scenario.relay, args.seed)?;
            let shafts = if args.aligned {
                offsets.map(|o| -o).to_vec()
            } else {
                settings
            };
            Relay::new(scenario.relay.clone(), offsets)?.render(
                &shafts,
                &CameraPose::nominal(args.station),
                0,
            )
        }
    };
    let png = frame.encode_png()?;
    std::fs::write(&args.out, png)
        .with_context(|| format!("cannot write {}", args.out.display()))?;
    crate::say!(
        "wrote {} ({}x{})",
        args.out.display(),
        frame.width(),
        frame.height()
    );
    Ok(())
}
