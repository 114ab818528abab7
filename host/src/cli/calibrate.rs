//! `optalign calibrate`: measure a bench's response and backlash from its camera.

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use optalign_protocol::{BacklashMode, Command};

use crate::lab::calibrate::{
    calibrate_backlash, calibrate_response, write_backlash_chart, write_response_chart,
};
use crate::lab::calibration::{ResponseCalibration, default_calibration_path};
use crate::lab::rigfile::task_axis_names;
use crate::lab::{LabRig, RigFile};
use crate::task::TaskKind;

#[derive(Debug, Args)]
pub struct CalibrateArgs {
    #[command(subcommand)]
    what: Calibration,
}

#[derive(Debug, Subcommand)]
enum Calibration {
    /// Fit one mirror's linear motor-to-pixel response from a grid scan.
    Response {
        /// The bench's rig file.
        #[arg(long, value_name = "FILE")]
        rig: PathBuf,
        /// Mirror number (Michelson 1-2, cavity 1, relay 1-4).
        #[arg(long)]
        mirror: usize,
        /// Half-width of the scan around the current position, steps (1 to 1,000,000).
        #[arg(long, default_value_t = 1500, value_parser = clap::value_parser!(i32).range(1..=1_000_000))]
        span: i32,
        /// Grid points per axis (2 to 21).
        #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u8).range(2..=21))]
        grid: u8,
        /// Calibration file to add the mirror to (default: the rig file's
        /// scoring.michelson_calibration, else response-calibration.json beside the rig file).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
    },
    /// Fit an axis's backlash from the hysteresis of the beam position.
    Backlash {
        #[arg(long, value_name = "FILE")]
        rig: PathBuf,
        /// Task axis name (as in the rig file's [axes] table).
        #[arg(long)]
        axis: String,
        /// How far the loop goes each way, steps (1 to 1,000,000).
        #[arg(long, default_value_t = 300, value_parser = clap::value_parser!(i32).range(1..=1_000_000))]
        amplitude: i32,
        /// Step between images, steps (1 to 100,000; at most 1,000 images each way).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(i32).range(1..=100_000))]
        step: i32,
        /// Write the fitted backlash into the controller's configuration and save it.
        #[arg(long)]
        write: bool,
    },
}

pub async fn run(args: CalibrateArgs) -> anyhow::Result<()> {
    match args.what {
        Calibration::Response {
            rig,
            mirror,
            span,
            grid,
            out,
        } => response(&rig, mirror, span, grid, out).await,
        Calibration::Backlash {
            rig,
            axis,
            amplitude,
            step,
            write,
        } => backlash(&rig, &axis, amplitude, step, write).await,
    }
}

/// Refuses to save a fit with doubts, saying each.
fn refuse_doubted(doubts: &[String], what: &str) -> anyhow::Result<()> {
    if doubts.is_empty() {
        return Ok(());
    }
    for doubt in doubts {
        crate::say!("  - {doubt}");
    }
    anyhow::bail!(
        "{what} is not trusted ({} reason{} above); nothing was saved",
        doubts.len(),
        if doubts.len() == 1 { "" } else { "s" }
    )
}

async fn response(
    rig: &Path,
    mirror: usize,
    span: i32,
    grid: u8,
    out: Option<PathBuf>,
) -> anyhow::Result<()> {
    let file = RigFile::load(rig)?;
    let named = file.scoring.michelson_calibration.clone();
    let task = file.task;
    let out = out.unwrap_or_else(|| default_calibration_path(rig, &file));
    // Read (or start) the file before anything moves, so a bad file costs no scan.
    let mut calibration = ResponseCalibration::load_or_new(&out)?;
    let mut bench = LabRig::connect_unscored(file).await?;
    let scan = calibrate_response(&mut bench, mirror, span, usize::from(grid)).await?;
    let frame = bench.capture().await?;
    let response = &scan.response;
    let m = response.matrix_px_per_step;
    crate::say!(
        "mirror {mirror}: [[{:.4}, {:.4}], [{:.4}, {:.4}]] px/step, centre ({:.1}, {:.1}) px at {:?} steps, residual {:.2} px RMS over {} images",
        m[0][0],
        m[0][1],
        m[1][0],
        m[1][1],
        response.centre_px[0],
        response.centre_px[1],
        response.reference_steps,
        response.residual_rms_px,
        response.points
    );
    let charts =
        write_response_chart(out.parent().unwrap_or(Path::new(".")), mirror, &scan.points)?;
    crate::say!("chart: {}", charts[0].display());
    refuse_doubted(&scan.doubts, &format!("mirror {mirror}'s response"))?;
    calibration.image_size_px = [frame.width(), frame.height()];
    calibration.set(scan.response);
    calibration.save(&out)?;
    crate::say!("wrote {}", out.display());
    if task == TaskKind::Michelson && named.as_deref() != Some(out.as_path()) {
        crate::say!(
            "to score runs with it, name it in {}: [scoring] michelson_calibration = {:?}",
            rig.display(),
            out.display().to_string()
        );
    }
    Ok(())
}

async fn backlash(
    rig: &Path,
    axis: &str,
    amplitude: i32,
    step: i32,
    write: bool,
) -> anyhow::Result<()> {
    let file = RigFile::load(rig)?;
    let names = task_axis_names(file.task);
    let index = names.iter().position(|n| n == axis).with_context(|| {
        format!(
            "--axis {axis}: not an axis of the {} task; use one of {}",
            file.task,
            names.join(", ")
        )
    })?;
    let mut bench = LabRig::connect_unscored(file).await?;
    let report = calibrate_backlash(&mut bench, index, amplitude, step).await?;
    let fit = &report.fit;
    crate::say!(
        "{axis}: backlash {:.1} ± {:.1} steps (response {:.4} px/step, residual {:.2} px RMS)",
        fit.backlash,
        fit.uncertainty,
        fit.gain,
        fit.residual_rms
    );
    let charts = write_backlash_chart(rig.parent().unwrap_or(Path::new(".")), axis, &report)?;
    crate::say!("chart: {}", charts[0].display());
    refuse_doubted(&report.doubts, &format!("{axis}'s backlash fit"))?;
    let (client, controller_axis) = bench.controller_axis(index);
    let steps = fit.backlash.round() as u16;
    if write {
        let mut config = client.get_config(controller_axis).await?;
        config.backlash = steps;
        if config.backlash_mode == BacklashMode::Off {
            config.backlash_mode = BacklashMode::OneSided;
        }
        client
            .command_ok(Command::SetConfig {
                axis: controller_axis,
                config,
            })
            .await?;
        client.command_ok(Command::SaveConfig).await?;
        crate::say!(
            "wrote backlash {steps} into the controller's axis {controller_axis} and saved it"
        );
    } else {
        crate::say!(
            "to use it: rerun with --write, or `optalign config --controller URL set {controller_axis} backlash={steps} --save`"
        );
    }
    Ok(())
}
