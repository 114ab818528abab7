//! Parameters of the Michelson interferometer scene (`[michelson]`).

use serde::{Deserialize, Serialize};

use super::check::Check;
use super::{NoiseParams, RealismParams, ScenarioError};

/// The Michelson scene: two returning Gaussian beams on one camera, each steered by one
/// two-axis mirror, interfering where they overlap.
///
/// Axis order of the shaft and offset arrays: 0 = mirror_1_axis_1 (horizontal),
/// 1 = mirror_1_axis_2 (vertical), 2 = mirror_2_axis_1 (horizontal), 3 = mirror_2_axis_2
/// (vertical). Beam k's centre in pixels (x right, y down) is the image centre plus
/// `mirror_k_sensitivity_px_per_step` times (shaft + offset) of mirror k's two axes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MichelsonParams {
    /// Image width in pixels. Default 1920 (the lab camera).
    pub width_px: u32,
    /// Image height in pixels. Default 1080.
    pub height_px: u32,
    /// Hidden offsets of the horizontal axes (0 and 2) are uniform in +-this many steps.
    /// Default 6144.
    pub horizontal_offset_range_steps: i32,
    /// Hidden offsets of the vertical axes (1 and 3) are uniform in +-this many steps.
    /// Default 4096.
    pub vertical_offset_range_steps: i32,
    /// Mirror 1's response, px per step: `[[dx/d axis_1, dx/d axis_2], [dy/d axis_1,
    /// dy/d axis_2]]`. Default `[[0.17, 0.012], [-0.01, -0.16]]`: about 1000 px for a
    /// 6144-step horizontal offset, so beams often start off the 1920 x 1080 screen.
    pub mirror_1_sensitivity_px_per_step: [[f64; 2]; 2],
    /// Mirror 2's response, same layout. Default `[[-0.165, -0.015], [0.012, 0.155]]`.
    pub mirror_2_sensitivity_px_per_step: [[f64; 2]; 2],
    /// 1/e^2 intensity radius of beams 1 and 2, px. Default `[130, 115]`.
    pub beam_radius_px: [f64; 2],
    /// Peak gray level of beams 1 and 2 alone, before saturation. Default `[150, 140]`:
    /// a single beam stays below saturation, constructive interference of both saturates.
    pub beam_peak_level: [f64; 2],
    /// Period of the straight fringes, px. Default 42.
    pub fringe_period_px: f64,
    /// Direction of the relative phase gradient, degrees from +x towards +y (down). Default 30.
    pub fringe_angle_deg: f64,
    /// Relative phase at the image centre, radians. Default 0 (bright fringe at the centre).
    pub fringe_phase_rad: f64,
    /// RMS wander of the relative phase from frame to frame, radians: vibration and air
    /// currents changing the path difference (the fringes drift across the overlap while
    /// nothing is commanded). Default 0.
    pub fringe_drift_rad: f64,
    /// Camera read-out.
    pub noise: NoiseParams,
    /// Realism layers (beam shapes, flicker, jitter, camera effects). All off by default.
    pub realism: RealismParams,
}

impl Default for MichelsonParams {
    fn default() -> Self {
        Self {
            width_px: 1920,
            height_px: 1080,
            horizontal_offset_range_steps: 6144,
            vertical_offset_range_steps: 4096,
            mirror_1_sensitivity_px_per_step: [[0.17, 0.012], [-0.01, -0.16]],
            mirror_2_sensitivity_px_per_step: [[-0.165, -0.015], [0.012, 0.155]],
            beam_radius_px: [130.0, 115.0],
            beam_peak_level: [150.0, 140.0],
            fringe_period_px: 42.0,
            fringe_angle_deg: 30.0,
            fringe_phase_rad: 0.0,
            fringe_drift_rad: 0.0,
            noise: NoiseParams::default(),
            realism: RealismParams::default(),
        }
    }
}

impl MichelsonParams {
    /// Checks every field; the error names the first bad one as `michelson.<field>`.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let check = Check::new("michelson");
        check.image_size(self.width_px, self.height_px)?;
        check.offset_range(
            "horizontal_offset_range_steps",
            self.horizontal_offset_range_steps,
        )?;
        check.offset_range(
            "vertical_offset_range_steps",
            self.vertical_offset_range_steps,
        )?;
        check.matrix(
            "mirror_1_sensitivity_px_per_step",
            &self.mirror_1_sensitivity_px_per_step,
        )?;
        check.matrix(
            "mirror_2_sensitivity_px_per_step",
            &self.mirror_2_sensitivity_px_per_step,
        )?;
        for k in 0..2 {
            check.gt(&format!("beam_radius_px[{k}]"), self.beam_radius_px[k], 0.0)?;
            check.ge(
                &format!("beam_peak_level[{k}]"),
                self.beam_peak_level[k],
                0.0,
            )?;
        }
        check.ge("fringe_period_px", self.fringe_period_px, 2.0)?;
        check.finite("fringe_angle_deg", self.fringe_angle_deg)?;
        check.finite("fringe_phase_rad", self.fringe_phase_rad)?;
        check.within("fringe_drift_rad", self.fringe_drift_rad, 0.0, 100.0)?;
        self.noise.validate("michelson.noise")?;
        self.realism.validate("michelson.realism")
    }

    /// The same scene seen by a camera of `width` x `height` coarser pixels covering the same
    /// field: every length in pixels shrinks by the binning factor and the read noise by it
    /// too (the noise of a block of pixels averaged). `None` when the realism layers are on
    /// (their pixel lengths are not rescaled), the aspect differs by more than a pixel, the
    /// camera would not be smaller, or the rescaled scene would be invalid (fringes finer
    /// than two pixels).
    pub fn binned(&self, width: u32, height: u32) -> Option<Self> {
        if self.realism != RealismParams::default()
            || width >= self.width_px
            || height >= self.height_px
        {
            return None;
        }
        let scale = f64::from(width) / f64::from(self.width_px);
        if (f64::from(self.height_px) * scale - f64::from(height)).abs() > 1.0 {
            return None;
        }
        let shrink = |m: [[f64; 2]; 2]| m.map(|row| row.map(|v| v * scale));
        let binned = Self {
            width_px: width,
            height_px: height,
            mirror_1_sensitivity_px_per_step: shrink(self.mirror_1_sensitivity_px_per_step),
            mirror_2_sensitivity_px_per_step: shrink(self.mirror_2_sensitivity_px_per_step),
            beam_radius_px: self.beam_radius_px.map(|r| r * scale),
            fringe_period_px: self.fringe_period_px * scale,
            noise: NoiseParams {
                std: self.noise.std * scale,
                ..self.noise.clone()
            },
            ..self.clone()
        };
        binned.validate().is_ok().then_some(binned)
    }

    /// The sensitivity matrix of mirror `k` (0 or 1).
    pub(crate) fn sensitivity(&self, k: usize) -> &[[f64; 2]; 2] {
        if k == 0 {
            &self.mirror_1_sensitivity_px_per_step
        } else {
            &self.mirror_2_sensitivity_px_per_step
        }
    }
}
