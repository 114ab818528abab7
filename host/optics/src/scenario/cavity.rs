//! Parameters of the two-mirror cavity scene (`[cavity]`).

use serde::{Deserialize, Serialize};

use super::check::Check;
use super::{NoiseParams, RealismParams, ScenarioError};

/// The cavity scene: a bright fixed primary beam, a dim secondary beam steered by the
/// in-coupler's two axes, stationary artefacts and noise, summed in intensity.
///
/// Axis order: 0 = x (motor 3), 1 = y (motor 1). The secondary's centre in pixels (x right,
/// y down) is the primary centre plus `secondary.sensitivity_px_per_step` times
/// (shaft + offset); shaft = -offset is the aligned reference.
///
/// Footprint relation: the primary's 1/e^2 radius is the footprint, and with the defaults
/// `primary.radius_px` (70) ~ `success_error_steps` (500) x the mean sensitivity
/// (0.14 px/step), so a 500-step error puts the secondary centre at the primary's edge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CavityParams {
    /// Image width in pixels. Default 1280.
    pub width_px: u32,
    /// Image height in pixels. Default 1024.
    pub height_px: u32,
    /// Hidden x (motor 3) offset uniform in +-this many steps. Default 6000.
    pub x_offset_range_steps: i32,
    /// Hidden y (motor 1) offset uniform in +-this many steps. Default 3750.
    pub y_offset_range_steps: i32,
    /// Error in motor steps at or below which the cavity counts as aligned. Default 500.
    pub success_error_steps: f64,
    /// The fixed single-pass beam.
    pub primary: PrimaryParams,
    /// The moving round-trip beam.
    pub secondary: SecondaryParams,
    /// Stationary diffraction ring around the primary.
    pub ring: RingParams,
    /// Stationary broad halo around the primary.
    pub halo: HaloParams,
    /// Stationary ghost spots (reflections off other surfaces) that never move.
    /// Default: two, one shaped much like the secondary.
    pub ghosts: Vec<GhostParams>,
    /// Camera read-out.
    pub noise: NoiseParams,
    /// Realism layers (the beams' shape, flicker, jitter, camera effects). All off by
    /// default. The beam profile shapes both the primary and the secondary (one laser).
    pub realism: RealismParams,
}

/// The primary beam: fixed on the image, bright enough to saturate its core.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PrimaryParams {
    /// Centre relative to the image centre, px (x right, y down). Default `[25, -15]`.
    pub centre_offset_px: [f64; 2],
    /// 1/e^2 intensity radius = the footprint radius, px. Default 70.
    pub radius_px: f64,
    /// Peak gray level before saturation. Default 1200: the core (about 0.9 radius) saturates.
    pub peak_level: f64,
}

/// The secondary beam: dim, smaller, translated linearly by the two motors.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SecondaryParams {
    /// 1/e^2 intensity radius, px. Default 35.
    pub radius_px: f64,
    /// Peak gray level. Default 40: clearly visible on the background, invisible on the
    /// saturated primary core.
    pub peak_level: f64,
    /// Response, px per step: `[[dx/dx_axis, dx/dy_axis], [dy/dx_axis, dy/dy_axis]]`.
    /// Default `[[-0.15, 0.012], [0.01, 0.13]]` (x moves left for positive motor 3 steps).
    /// With +-6000 steps of x offset the secondary starts off-screen for |x| > ~4100 steps.
    pub sensitivity_px_per_step: [[f64; 2]; 2],
}

/// A thin stationary ring centred on the primary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RingParams {
    /// Ring radius, px. Default 170.
    pub radius_px: f64,
    /// Gaussian half-width of the ring's cross-section, px. Default 6.
    pub width_px: f64,
    /// Peak gray level of the ring. Default 18.
    pub level: f64,
}

/// A broad stationary halo centred on the primary.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct HaloParams {
    /// 1/e^2 radius, px. Default 260.
    pub radius_px: f64,
    /// Peak gray level. Default 14.
    pub level: f64,
}

/// One stationary ghost spot.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GhostParams {
    /// Centre relative to the image centre, px (x right, y down). Default `[310, -190]`.
    pub centre_offset_px: [f64; 2],
    /// 1/e^2 radius, px. Default 30.
    pub radius_px: f64,
    /// Peak gray level. Default 38.
    pub peak_level: f64,
}

impl Default for CavityParams {
    fn default() -> Self {
        Self {
            width_px: 1280,
            height_px: 1024,
            x_offset_range_steps: 6000,
            y_offset_range_steps: 3750,
            success_error_steps: 500.0,
            primary: PrimaryParams::default(),
            secondary: SecondaryParams::default(),
            ring: RingParams::default(),
            halo: HaloParams::default(),
            ghosts: vec![
                GhostParams::default(),
                GhostParams {
                    centre_offset_px: [-380.0, 240.0],
                    radius_px: 18.0,
                    peak_level: 55.0,
                },
            ],
            noise: NoiseParams::default(),
            realism: RealismParams::default(),
        }
    }
}

impl Default for PrimaryParams {
    fn default() -> Self {
        Self {
            centre_offset_px: [25.0, -15.0],
            radius_px: 70.0,
            peak_level: 1200.0,
        }
    }
}

impl Default for SecondaryParams {
    fn default() -> Self {
        Self {
            radius_px: 35.0,
            peak_level: 40.0,
            sensitivity_px_per_step: [[-0.15, 0.012], [0.01, 0.13]],
        }
    }
}

impl Default for RingParams {
    fn default() -> Self {
        Self {
            radius_px: 170.0,
            width_px: 6.0,
            level: 18.0,
        }
    }
}

impl Default for HaloParams {
    fn default() -> Self {
        Self {
            radius_px: 260.0,
            level: 14.0,
        }
    }
}

impl Default for GhostParams {
    fn default() -> Self {
        Self {
            centre_offset_px: [310.0, -190.0],
            radius_px: 30.0,
            peak_level: 38.0,
        }
    }
}

impl CavityParams {
    /// Checks every field; the error names the first bad one as `cavity.<field>`.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let check = Check::new("cavity");
        check.image_size(self.width_px, self.height_px)?;
        check.offset_range("x_offset_range_steps", self.x_offset_range_steps)?;
        check.offset_range("y_offset_range_steps", self.y_offset_range_steps)?;
        check.ge("success_error_steps", self.success_error_steps, 0.0)?;

        let primary = Check::new("cavity.primary");
        primary.finite("centre_offset_px[0]", self.primary.centre_offset_px[0])?;
        primary.finite("centre_offset_px[1]", self.primary.centre_offset_px[1])?;
        primary.gt("radius_px", self.primary.radius_px, 0.0)?;
        primary.ge("peak_level", self.primary.peak_level, 0.0)?;

        let secondary = Check::new("cavity.secondary");
        secondary.gt("radius_px", self.secondary.radius_px, 0.0)?;
        secondary.ge("peak_level", self.secondary.peak_level, 0.0)?;
        secondary.matrix(
            "sensitivity_px_per_step",
            &self.secondary.sensitivity_px_per_step,
        )?;

        let ring = Check::new("cavity.ring");
        ring.ge("radius_px", self.ring.radius_px, 0.0)?;
        ring.gt("width_px", self.ring.width_px, 0.0)?;
        ring.ge("level", self.ring.level, 0.0)?;

        let halo = Check::new("cavity.halo");
        halo.gt("radius_px", self.halo.radius_px, 0.0)?;
        halo.ge("level", self.halo.level, 0.0)?;

        for (i, ghost) in self.ghosts.iter().enumerate() {
            let path = format!("cavity.ghosts[{i}]");
            let g = Check::new(&path);
            g.finite("centre_offset_px[0]", ghost.centre_offset_px[0])?;
            g.finite("centre_offset_px[1]", ghost.centre_offset_px[1])?;
            g.gt("radius_px", ghost.radius_px, 0.0)?;
            g.ge("peak_level", ghost.peak_level, 0.0)?;
        }
        self.noise.validate("cavity.noise")?;
        self.realism.validate("cavity.realism")
    }
}
