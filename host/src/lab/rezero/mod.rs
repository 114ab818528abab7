//! `optalign rezero`: finding axes whose position the controllers lost (a power cut in the
//! middle of a move) from the camera and the rig's response calibration, and declaring
//! them. The Michelson's mirrors are read from each beam's centre through the inverse
//! response; the cavity's in-coupler from the secondary beam's offset to the primary,
//! against that offset in the calibration (so a camera that shifted since does not matter). Lost axes move only relatively, in the controllers'
//! recovery mode, every measuring position approached from the same side. Positions are
//! declared with one standard deviation, from the calibration's residual and the
//! detector's covariance; when a beam cannot be found or an uncertainty is above the
//! limit, nothing is declared.

mod locate;
mod mirror;
mod walk;

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};

use self::locate::Response;
use self::mirror::{Mirror, Reading};
use super::calibration::{ResponseCalibration, default_calibration_path};
use super::rig::LabRig;
use super::rigfile::{RigFile, task_axis_names};
use super::scoring::CAVITY_SUCCESS_STEPS;
use crate::task::TaskKind;

/// By default an axis is declared when its standard uncertainty is at most this share of
/// the task's tolerance in steps.
pub const DEFAULT_UNCERTAINTY_SHARE: f64 = 0.05;

/// Search rings by default: up to this many search steps (a third of the image's smaller
/// side each) from where the axes are.
pub const DEFAULT_SEARCH_RINGS: i32 = 4;

/// What `rezero` needs besides the bench.
#[derive(Clone, Debug)]
pub struct RezeroSetup {
    pub calibration: ResponseCalibration,
    pub calibration_path: PathBuf,
    /// The largest standard uncertainty to declare, steps; `None`: the task's default
    /// ([`DEFAULT_UNCERTAINTY_SHARE`] of its tolerance).
    pub max_uncertainty_steps: Option<f64>,
    pub search_rings: i32,
}

impl RezeroSetup {
    /// The setup for the bench of `rig` (read from `rig_path`): its response calibration
    /// from `calibration`, or where `optalign calibrate response` writes it.
    pub fn for_rig(
        rig_path: &Path,
        rig: &RigFile,
        calibration: Option<PathBuf>,
        max_uncertainty_steps: Option<f64>,
        search_rings: i32,
    ) -> anyhow::Result<Self> {
        let calibration_path =
            calibration.unwrap_or_else(|| default_calibration_path(rig_path, rig));
        let loaded = ResponseCalibration::load(&calibration_path).with_context(|| {
            "rezero finds lost axes through the bench's response calibration: run `optalign calibrate response` first (while positions are known), or name the file with --calibration"
        })?;
        if let Some(max) = max_uncertainty_steps {
            anyhow::ensure!(
                max.is_finite() && max > 0.0,
                "--max-uncertainty must be a positive number of steps, got {max}"
            );
        }
        anyhow::ensure!(
            (0..=20).contains(&search_rings),
            "--search-rings must be 0 to 20, got {search_rings}"
        );
        Ok(Self {
            calibration: loaded,
            calibration_path,
            max_uncertainty_steps,
            search_rings,
        })
    }
}

/// One lost axis found and declared.
#[derive(Clone, Debug, PartialEq)]
pub struct Declared {
    /// Task axis index and name.
    pub axis: usize,
    pub name: String,
    /// What its controller counted before (task steps).
    pub counter: i32,
    /// The position declared (task steps).
    pub position: i32,
    /// One standard deviation, steps.
    pub sigma_steps: f64,
}

/// Finds every lost axis of the bench and declares it. `narrate` gets a line for each
/// thing done. When a beam cannot be found, or an axis's uncertainty is above the limit,
/// the error says why and nothing is declared (the axes are brought back to where they
/// started). The visible settings restart at 0 afterwards.
pub async fn rezero(
    rig: &mut LabRig,
    setup: &RezeroSetup,
    narrate: &mut dyn FnMut(&str),
) -> anyhow::Result<Vec<Declared>> {
    let lost = rig.lost_axes().await?;
    let names = task_axis_names(rig.rig_file().task);
    if lost.is_empty() {
        narrate("no axis has lost its position; nothing to do");
        return Ok(Vec::new());
    }
    narrate(&format!(
        "lost positions: {}",
        lost.iter()
            .map(|&a| names[a].as_str())
            .collect::<Vec<_>>()
            .join(", ")
    ));
    let frame = rig.capture().await?;
    let size = [frame.width(), frame.height()];
    anyhow::ensure!(
        setup.calibration.image_size_px == size,
        "the response calibration {} was made on {} x {} px images, the camera gives {} x {} px; nothing was declared",
        setup.calibration_path.display(),
        setup.calibration.image_size_px[0],
        setup.calibration.image_size_px[1],
        size[0],
        size[1]
    );
    let mirrors = mirrors(rig.rig_file(), setup, &lost)?;
    let mut found = Vec::new();
    for mirror in &mirrors {
        let result = mirror::find(rig, mirror, setup.search_rings, narrate)
            .await
            .map_err(|error| error.context("nothing was declared"))?;
        let limit = setup
            .max_uncertainty_steps
            .unwrap_or_else(|| default_max_uncertainty(rig.rig_file(), mirror));
        for (i, &k) in mirror.lost.iter().enumerate() {
            let sigma = result.sigma[i];
            if sigma > limit {
                bail!(
                    "{}: found to ± {sigma:.1} steps (one standard deviation), more than --max-uncertainty {limit:.1}; nothing was declared. Recalibrate the response (`optalign calibrate response`) or average more: lower the camera noise",
                    names[mirror.axes[k]]
                );
            }
        }
        found.push((mirror, result));
    }
    let counters = rig.counters().await?;
    let mut declared = Vec::new();
    for (mirror, result) in &found {
        for (i, &k) in mirror.lost.iter().enumerate() {
            let axis = mirror.axes[k];
            let position = f64::from(counters[axis]) + result.steps[i];
            let position = position.round() as i32;
            declared.push(Declared {
                axis,
                name: names[axis].clone(),
                counter: counters[axis],
                position,
                sigma_steps: result.sigma[i],
            });
        }
    }
    for entry in &declared {
        rig.declare(entry.axis, entry.position).await?;
        narrate(&format!(
            "{}: declared at {} steps ± {:.1} (one standard deviation; the controller counted {})",
            entry.name, entry.position, entry.sigma_steps, entry.counter
        ));
    }
    rig.restart_origin().await?;
    Ok(declared)
}

/// The mirrors with lost axes, each with how its beam is read.
fn mirrors(rig: &RigFile, setup: &RezeroSetup, lost: &[usize]) -> anyhow::Result<Vec<Mirror>> {
    let names = task_axis_names(rig.task);
    let calibration = &setup.calibration;
    let path = setup.calibration_path.display();
    let entry = |mirror: usize| {
        calibration.mirror(mirror).with_context(|| {
            format!(
                "{path} has no response of mirror {mirror}: run `optalign calibrate response --mirror {mirror}` while its positions are known; nothing was declared"
            )
        })
    };
    let mut mirrors = Vec::new();
    match rig.task {
        TaskKind::Michelson => {
            for mirror in [1, 2] {
                let axes = [2 * (mirror - 1), 2 * (mirror - 1) + 1];
                let lost_here: Vec<usize> = (0..2).filter(|&k| lost.contains(&axes[k])).collect();
                if lost_here.is_empty() {
                    continue;
                }
                let response = entry(mirror)?;
                mirrors.push(Mirror {
                    name: format!("mirror {mirror}"),
                    axes,
                    lost: lost_here,
                    reading: Reading::Absolute(Response {
                        anchor_px: response.centre_px,
                        reference_steps: response.reference_steps,
                        matrix: response.matrix_px_per_step,
                        residual_px: response.residual_rms_px,
                    }),
                });
            }
        }
        TaskKind::Cavity => {
            let response = entry(1)?;
            let primary = response.stationary_px.with_context(|| {
                format!(
                    "{path} does not record where the primary beam was when the in-coupler was calibrated (an older calibration): run `optalign calibrate response --mirror 1` again while its positions are known; nothing was declared"
                )
            })?;
            mirrors.push(Mirror {
                name: "the in-coupler".into(),
                axes: [0, 1],
                lost: (0..2).filter(|k| lost.contains(k)).collect(),
                // The secondary's offset from the primary, as calibrated.
                reading: Reading::FromStationary(Response {
                    anchor_px: [
                        response.centre_px[0] - primary[0],
                        response.centre_px[1] - primary[1],
                    ],
                    reference_steps: response.reference_steps,
                    matrix: response.matrix_px_per_step,
                    residual_px: response.residual_rms_px,
                }),
            });
        }
        TaskKind::Relay => bail!(
            "rezero finds lost positions on the Michelson and the cavity so far; on the relay ({}) declare them by hand with `optalign set-position` after realigning; nothing was declared",
            lost.iter()
                .map(|&a| names[a].as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
    Ok(mirrors)
}

/// The default limit on an axis's uncertainty: [`DEFAULT_UNCERTAINTY_SHARE`] of the task's
/// tolerance in steps (Michelson: of half the success error, through the mirror's most
/// sensitive direction; cavity: of its 500-step success rule).
fn default_max_uncertainty(rig: &RigFile, mirror: &Mirror) -> f64 {
    match &mirror.reading {
        Reading::Absolute(response) => {
            let m = response.matrix;
            let largest = nalgebra::Matrix2::new(m[0][0], m[0][1], m[1][0], m[1][1])
                .singular_values()
                .max();
            DEFAULT_UNCERTAINTY_SHARE * (rig.limits.michelson.success_error_px / 2.0) / largest
        }
        Reading::FromStationary(_) => DEFAULT_UNCERTAINTY_SHARE * CAVITY_SUCCESS_STEPS,
    }
}
