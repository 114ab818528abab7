//! `optalign calibrate backlash`: move one axis forward and back in steps around a visible
//! beam with the controller's compensation off, and fit the dead band from the hysteresis
//! of the beam position (a linear response through a play operator).

use anyhow::{Context, bail};
use optalign_protocol::{AxisConfig, BacklashMode, Command};

use super::fit::{BacklashFit, fit_backlash};
use super::track;
use super::trust::{backlash_doubts, detector_sigma};
use crate::imaging::{Picture, find_beams};
use crate::lab::rig::LabRig;
use crate::lab::rigfile::task_axis_names;
use crate::rig::Rig;

/// The measured loop, its fit, and why the fit is not to be trusted (empty when it is).
#[derive(Clone, Debug)]
pub struct BacklashReport {
    pub fit: BacklashFit,
    /// (commanded steps, beam position along the axis's direction of motion, px).
    pub samples: Vec<(f64, f64)>,
    pub doubts: Vec<String>,
}

/// Commands of the loop: out to +amplitude, back to -amplitude, out again, home.
fn loop_commands(amplitude: i32, step: i32) -> Vec<i32> {
    let ramp = |from: i32, to: i32| -> Vec<i32> {
        let direction = if to >= from { step } else { -step };
        let count = (to - from).abs() / step;
        (1..=count).map(|i| from + i * direction).collect()
    };
    let mut commands = vec![0];
    for (from, to) in [
        (0, amplitude),
        (amplitude, -amplitude),
        (-amplitude, amplitude),
        (amplitude, 0),
    ] {
        commands.extend(ramp(from, to));
    }
    commands
}

/// The most images the loop takes each way (a longer scan is a typing mistake).
const MOST_IMAGES_EACH_WAY: i64 = 1000;

/// Runs the loop on task axis `axis`; compensation is switched off for the scan and the
/// previous configuration is restored on every path.
pub async fn calibrate_backlash(
    rig: &mut LabRig,
    axis: usize,
    amplitude: i32,
    step: i32,
) -> anyhow::Result<BacklashReport> {
    let images = i64::from(amplitude) / i64::from(step.max(1));
    anyhow::ensure!(
        step > 0 && (4..=MOST_IMAGES_EACH_WAY).contains(&images),
        "--amplitude {amplitude} with --step {step} takes {images} images each way; \
         from 4 to {MOST_IMAGES_EACH_WAY}: --amplitude must be at least four --step"
    );
    let (client, controller_axis) = rig.controller_axis(axis);
    let saved = client.get_config(controller_axis).await?;
    let scan = AxisConfig {
        backlash_mode: BacklashMode::Off,
        ..saved
    };
    client
        .command_ok(Command::SetConfig {
            axis: controller_axis,
            config: scan,
        })
        .await?;
    let result = scan_loop(rig, axis, amplitude, step).await;
    let (client, controller_axis) = rig.controller_axis(axis);
    let restored = client
        .command_ok(Command::SetConfig {
            axis: controller_axis,
            config: saved,
        })
        .await;
    let report = result?;
    restored.context("restoring the axis configuration after the scan")?;
    Ok(report)
}

async fn scan_loop(
    rig: &mut LabRig,
    axis: usize,
    amplitude: i32,
    step: i32,
) -> anyhow::Result<BacklashReport> {
    let name = task_axis_names(rig.task())[axis].clone();
    let start = rig.commanded()[axis];
    let before = Picture::new(&rig.capture().await?);
    if find_beams(&before).is_empty() {
        bail!(
            "no beam is visible in the camera image; bring the beam into view before calibrating backlash"
        );
    }
    // The probe goes out on the negative side and comes back, so the loop starts pressed
    // against the positive side as the fit assumes.
    rig.move_to(&[(axis, start - amplitude)]).await?;
    let after = Picture::new(&rig.capture().await?);
    rig.move_to(&[(axis, start)]).await?;
    let probe = track::probe(&before, &after).with_context(|| {
        format!(
            "no beam moved when {name} moved by -{amplitude} steps (or the one that did left the view); nothing was written. Check the wiring and the rig file's [axes] map; if the dead band is wider than {amplitude} steps use a larger --amplitude"
        )
    })?;
    let mut tracked = probe.from.centre;
    let mut commands = Vec::new();
    let mut positions = Vec::new();
    let mut uncertainties = Vec::new();
    for offset in loop_commands(amplitude, step) {
        rig.move_to(&[(axis, start + offset)]).await?;
        let beams = find_beams(&Picture::new(&rig.capture().await?));
        let Some(beam) = probe.track(&beams, tracked).copied() else {
            rig.move_to(&[(axis, start)]).await?;
            bail!(
                "the moving beam left the image (or met another beam) at {offset:+} steps; nothing was written. Use a smaller --amplitude"
            );
        };
        let Some(centre) = track::measured_centre(&beam) else {
            rig.move_to(&[(axis, start)]).await?;
            bail!(
                "the image border cuts the moving beam at {offset:+} steps too deeply to measure its centre; nothing was written. Bring the beam towards the image centre or use a smaller --amplitude"
            );
        };
        tracked = beam.centre;
        commands.push(f64::from(offset));
        positions.push(centre);
        uncertainties.push(beam.uncertainty);
    }
    rig.move_to(&[(axis, start)]).await?;
    let along = project_on_motion(&positions);
    let fit = fit_backlash(&commands, &along, f64::from(amplitude), 1.0)
        .context("the loop did not give enough points to fit a dead band")?;
    let doubts = backlash_doubts(
        &fit,
        &name,
        f64::from(amplitude),
        f64::from(step),
        detector_sigma(&uncertainties),
    );
    Ok(BacklashReport {
        fit,
        samples: commands.into_iter().zip(along).collect(),
        doubts,
    })
}

/// Positions projected on their principal direction (the line the beam moves along).
fn project_on_motion(positions: &[[f64; 2]]) -> Vec<f64> {
    let n = positions.len() as f64;
    let mean = [0, 1].map(|k| positions.iter().map(|p| p[k]).sum::<f64>() / n);
    let (mut sxx, mut sxy, mut syy) = (0.0, 0.0, 0.0);
    for p in positions {
        let (dx, dy) = (p[0] - mean[0], p[1] - mean[1]);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
    }
    let angle = 0.5 * (2.0 * sxy).atan2(sxx - syy);
    let (c, s) = (angle.cos(), angle.sin());
    positions
        .iter()
        .map(|p| (p[0] - mean[0]) * c + (p[1] - mean[1]) * s)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_loop_reverses_twice_and_comes_home() {
        let commands = loop_commands(100, 25);
        assert_eq!(commands.first(), Some(&0));
        assert_eq!(commands.last(), Some(&0));
        assert_eq!(commands.iter().max(), Some(&100));
        assert_eq!(commands.iter().min(), Some(&-100));
        assert_eq!(commands.len(), 1 + 4 + 8 + 8 + 4);
    }

    #[test]
    fn projection_follows_the_direction_of_motion() {
        let positions: Vec<[f64; 2]> = (0..5)
            .map(|i| [3.0 * f64::from(i), 4.0 * f64::from(i)])
            .collect();
        let along = project_on_motion(&positions);
        assert!(((along[4] - along[0]).abs() - 20.0).abs() < 1e-9);
    }
}
