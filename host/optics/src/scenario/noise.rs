//! Camera read-out parameters shared by the three scenes: dark level, read noise, saturation,
//! depth.

use serde::{Deserialize, Serialize};

use super::ScenarioError;
use super::check::Check;

/// Camera read-out: what an unlit pixel looks like and where bright pixels clip.
///
/// Noise is approximately Gaussian (a sum of four uniform bytes), independent per pixel, and
/// fully determined by the scene's hidden offsets, `seed` and the frame index.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseParams {
    /// Mean gray level of an unlit pixel. Default 6.
    pub background_level: f64,
    /// Standard deviation of the per-pixel read noise, in gray levels. Default 2.5.
    pub std: f64,
    /// Gray level at which pixels saturate (at most 255). Default 255.
    pub saturation_level: f64,
    /// The frames' depth: 8 (8-bit), 12 (12-bit data in 16-bit words, full scale 4095) or 16
    /// bits. Levels and noise are in gray levels of an 8-bit frame at every depth; deeper
    /// frames keep their fractions. Default 8.
    pub bits: u8,
    /// Mixed into the noise stream; change it for another noise realisation of the same scene.
    /// Default 0.
    pub seed: u64,
}

impl Default for NoiseParams {
    fn default() -> Self {
        Self {
            background_level: 6.0,
            std: 2.5,
            saturation_level: 255.0,
            bits: 8,
            seed: 0,
        }
    }
}

impl NoiseParams {
    pub(crate) fn validate(&self, prefix: &str) -> Result<(), ScenarioError> {
        let check = Check::new(prefix);
        check.within("background_level", self.background_level, 0.0, 255.0)?;
        check.within("std", self.std, 0.0, 100.0)?;
        check.within("saturation_level", self.saturation_level, 1.0, 255.0)?;
        if ![8, 12, 16].contains(&self.bits) {
            return Err(ScenarioError::Invalid {
                field: check.path("bits"),
                reason: format!("must be 8, 12 or 16, got {}", self.bits),
            });
        }
        Ok(())
    }

    /// The largest pixel value of the frames: 255, 4095 or 65535.
    pub fn full_scale(&self) -> u16 {
        match self.bits {
            12 => crate::frame::FULL_SCALE_12,
            16 => crate::frame::FULL_SCALE_16,
            _ => crate::frame::FULL_SCALE_8,
        }
    }
}
