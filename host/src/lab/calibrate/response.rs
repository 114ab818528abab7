//! `optalign calibrate response`: scan a grid of positions of one mirror's two axes while the
//! other axes hold, find that mirror's beam in each image, and fit the linear
//! motor-to-pixel model the paper uses to initialise and score runs.

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use super::fit::fit_affine;
use crate::imaging::{Picture, find_beams, nearest};
use crate::lab::calibration::MirrorResponse;
use crate::lab::rig::LabRig;
use crate::lab::rigfile::task_axis_names;
use crate::rig::Rig;
use crate::task::TaskKind;

/// One grid point: where the axes were and where the beam was seen.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ResponsePoint {
    pub steps: [f64; 2],
    pub measured_px: [f64; 2],
    pub fitted_px: [f64; 2],
}

/// The two task axes of mirror `mirror` (1-based).
pub fn mirror_axes(task: TaskKind, mirror: usize) -> anyhow::Result<[usize; 2]> {
    let mirrors = match task {
        TaskKind::Michelson => 2,
        TaskKind::Cavity => 1,
        TaskKind::Relay => 4,
    };
    if !(1..=mirrors).contains(&mirror) {
        bail!("--mirror {mirror}: the {task} task has mirrors 1..={mirrors}");
    }
    Ok([2 * (mirror - 1), 2 * (mirror - 1) + 1])
}

/// Scans a `grid` x `grid` pattern of half-width `span` steps around the current position.
pub async fn calibrate_response(
    rig: &mut LabRig,
    mirror: usize,
    span: i32,
    grid: usize,
) -> anyhow::Result<(MirrorResponse, Vec<ResponsePoint>)> {
    anyhow::ensure!(grid >= 2, "--grid must be at least 2");
    anyhow::ensure!(span > 0, "--span must be a positive number of steps");
    let axes = mirror_axes(rig.task(), mirror)?;
    let start = rig.commanded().to_vec();
    let first = find_beams(&Picture::new(&rig.capture().await?));
    if first.is_empty() {
        bail!(
            "no beam is visible in the camera image; bring mirror {mirror}'s beam into view before calibrating"
        );
    }
    // Which beam is this mirror's: the one that moves when its first axis moves.
    let probe = span / 2;
    rig.move_to(&[(axes[0], start[axes[0]] + probe)]).await?;
    let moved = find_beams(&Picture::new(&rig.capture().await?));
    let ours = moved
        .iter()
        .map(|b| (b, nearest(&first, b.centre).map_or(f64::INFINITY, |n| distance(n.centre, b.centre))))
        .max_by(|a, b| a.1.total_cmp(&b.1))
        .filter(|(_, shift)| *shift > 2.0)
        .map(|(beam, _)| *beam)
        .with_context(|| format!("no beam moved when mirror {mirror}'s first axis moved by {probe} steps; check the wiring and the rig file's axis map"))?;

    let mut steps = Vec::new();
    let mut measured = Vec::new();
    let mut last = ours;
    let offsets: Vec<i32> = (0..grid)
        .map(|i| -span + (2 * span * i as i32) / (grid as i32 - 1))
        .collect();
    for (row, &da) in offsets.iter().enumerate() {
        // Serpentine order keeps moves short.
        let columns: Vec<i32> = if row % 2 == 0 {
            offsets.clone()
        } else {
            offsets.iter().rev().copied().collect()
        };
        for db in columns {
            let target = [start[axes[0]] + da, start[axes[1]] + db];
            rig.move_to(&[(axes[0], target[0]), (axes[1], target[1])])
                .await?;
            let beams = find_beams(&Picture::new(&rig.capture().await?));
            let prediction = fit_affine(&steps, &measured)
                .map(|fit| fit.predict([f64::from(target[0]), f64::from(target[1])]))
                .unwrap_or(last.centre);
            let Some(beam) = nearest(&beams, prediction) else {
                tracing::warn!(?target, "beam not visible at this grid point; skipped");
                continue;
            };
            last = *beam;
            let positions = rig.task_positions();
            steps.push([positions[axes[0]], positions[axes[1]]]);
            measured.push(beam.centre);
        }
    }
    rig.move_to(&[(axes[0], start[axes[0]]), (axes[1], start[axes[1]])])
        .await?;
    let fit = fit_affine(&steps, &measured)
        .context("too few grid points showed the beam to fit a response; use a smaller --span")?;
    let points = steps
        .iter()
        .zip(&measured)
        .map(|(s, m)| ResponsePoint {
            steps: *s,
            measured_px: *m,
            fitted_px: fit.predict(*s),
        })
        .collect();
    let names = task_axis_names(rig.task());
    Ok((
        MirrorResponse {
            mirror,
            axes: [names[axes[0]].clone(), names[axes[1]].clone()],
            axis_indices: axes,
            reference_steps: fit.reference,
            centre_px: fit.centre,
            matrix_px_per_step: fit.matrix,
            residual_rms_px: fit.residual_rms,
            points: steps.len(),
        },
        points,
    ))
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}
