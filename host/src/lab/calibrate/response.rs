//! `optalign calibrate response`: scan a grid of positions of one mirror's two axes while the
//! other axes hold, find that mirror's beam in each image, and fit the linear
//! motor-to-pixel model the paper uses to initialise and score runs.

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use super::fit::fit_affine;
use super::track;
use super::trust::{detector_sigma, response_doubts};
use crate::imaging::{Picture, find_beams, strongest};
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

/// A response scan: the fit, the points behind it, and why it is not to be trusted (empty
/// when it is).
#[derive(Clone, Debug)]
pub struct ResponseScan {
    pub response: MirrorResponse,
    pub points: Vec<ResponsePoint>,
    pub doubts: Vec<String>,
}

/// Scans a `grid` x `grid` pattern of half-width `span` steps around the current position.
/// The mirror's beam is the one that moves when its first axis moves (told by the frames'
/// difference); beams that stay put are never followed.
pub async fn calibrate_response(
    rig: &mut LabRig,
    mirror: usize,
    span: i32,
    grid: usize,
) -> anyhow::Result<ResponseScan> {
    anyhow::ensure!(grid >= 2, "--grid must be at least 2");
    anyhow::ensure!(span > 0, "--span must be a positive number of steps");
    let axes = mirror_axes(rig.task(), mirror)?;
    let names = task_axis_names(rig.task());
    let start = rig.commanded().to_vec();
    let before = Picture::new(&rig.capture().await?);
    if find_beams(&before).is_empty() {
        bail!(
            "no beam is visible in the camera image; bring mirror {mirror}'s beam into view before calibrating"
        );
    }
    let probe_steps = span / 2;
    rig.move_to(&[(axes[0], start[axes[0]] + probe_steps)])
        .await?;
    let after = Picture::new(&rig.capture().await?);
    let Some(probe) = track::probe(&before, &after) else {
        rig.move_to(&[(axes[0], start[axes[0]])]).await?;
        bail!(
            "no beam moved when {} moved by {probe_steps} steps (or the one that did left the view); nothing was saved. Check the wiring and the rig file's [axes] map, or use a smaller --span",
            names[axes[0]]
        );
    };

    let mut steps = Vec::new();
    let mut measured = Vec::new();
    let mut uncertainties = Vec::new();
    let mut last = probe.to.centre;
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
            // The fit is in task positions, not in the visible settings of `target`.
            let positions = rig.task_positions();
            let at = [positions[axes[0]], positions[axes[1]]];
            let beams = find_beams(&Picture::new(&rig.capture().await?));
            let prediction = fit_affine(&steps, &measured)
                .map(|fit| fit.predict(at))
                .unwrap_or(last);
            let Some(beam) = probe.track(&beams, prediction) else {
                tracing::warn!(
                    ?target,
                    "the moving beam is not visible apart from the others at this grid point; skipped"
                );
                continue;
            };
            last = beam.centre;
            let Some(centre) = track::measured_centre(beam) else {
                tracing::warn!(
                    ?target,
                    "the image border cuts the moving beam at this grid point too deeply to measure its centre; skipped"
                );
                continue;
            };
            steps.push(at);
            measured.push(centre);
            uncertainties.push(beam.uncertainty);
        }
    }
    rig.move_to(&[(axes[0], start[axes[0]]), (axes[1], start[axes[1]])])
        .await?;
    let fit = fit_affine(&steps, &measured).with_context(|| {
        format!(
            "only {} of {} grid points showed the moving beam whole and apart from the others, too few to fit a response; nothing was saved. Bring the beam towards the image centre, use a smaller --span, or move the other beams away",
            steps.len(),
            grid * grid
        )
    })?;
    let sigma = detector_sigma(&uncertainties);
    let doubts = response_doubts(
        &fit,
        [&names[axes[0]], &names[axes[1]]],
        f64::from(span),
        sigma,
    );
    let points = steps
        .iter()
        .zip(&measured)
        .map(|(s, m)| ResponsePoint {
            steps: *s,
            measured_px: *m,
            fitted_px: fit.predict(*s),
        })
        .collect();
    Ok(ResponseScan {
        response: MirrorResponse {
            mirror,
            axes: [names[axes[0]].clone(), names[axes[1]].clone()],
            axis_indices: axes,
            reference_steps: fit.reference,
            centre_px: fit.centre,
            matrix_px_per_step: fit.matrix,
            residual_rms_px: fit.residual_rms,
            points: steps.len(),
            stationary_px: strongest(&probe.stationary)
                .map(|beam| track::anchor_centre(&before, beam)),
        },
        points,
        doubts,
    })
}
