//! The cavity task: two absolute axes (x = motor 3, y = motor 1), a 50-evaluation budget,
//! scored by the distance in motor steps from the aligned reference, success at <= 500.

use serde::{Deserialize, Serialize};

use super::{Range, check_absolute, check_budget};

/// Command names, in axis order.
pub const AXIS_NAMES: [&str; 2] = ["x", "y"];

/// Bounds and budget (`[tasks.cavity]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct CavityLimits {
    /// Evaluations per run. Default 50.
    pub budget: usize,
    /// Absolute range of x (motor 3) and y (motor 1). Default +-8000 and +-5000.
    pub ranges: [Range; 2],
}

impl Default for CavityLimits {
    fn default() -> Self {
        Self {
            budget: 50,
            ranges: [Range::symmetric(8000), Range::symmetric(5000)],
        }
    }
}

impl CavityLimits {
    pub fn validate(&self) -> Result<(), String> {
        check_budget("tasks.cavity.budget", self.budget)?;
        for (name, range) in AXIS_NAMES.iter().zip(&self.ranges) {
            if range.min > 0 || range.max < 0 {
                return Err(format!(
                    "tasks.cavity.ranges ({name}): {range} must contain the start setting 0"
                ));
            }
        }
        Ok(())
    }

    pub fn check(&self, command: &[i32; 2]) -> Result<(), String> {
        check_absolute(&AXIS_NAMES, &self.ranges, command)
    }
}

/// The score of a cavity state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct CavityScore {
    /// Distance of the true motor positions from the aligned reference, steps.
    pub error_steps: f64,
    pub success: bool,
    /// Where the secondary beam really is, px (for comparing with the agent's claims);
    /// unknown on a bench.
    pub secondary_centre_px: Option<[f64; 2]>,
}
