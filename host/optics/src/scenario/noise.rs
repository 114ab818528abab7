//! Camera read-out parameters shared by the three scenes: dark level, read noise, saturation.

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
            seed: 0,
        }
    }
}

impl NoiseParams {
    pub(crate) fn validate(&self, prefix: &str) -> Result<(), ScenarioError> {
        let check = Check::new(prefix);
        check.within("background_level", self.background_level, 0.0, 255.0)?;
        check.within("std", self.std, 0.0, 100.0)?;
        check.within("saturation_level", self.saturation_level, 1.0, 255.0)
    }
}
