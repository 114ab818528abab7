//! The Michelson task: four absolute axes, a 60-evaluation budget, scored by the summed
//! distance of both beam centres from the image centre.

use serde::{Deserialize, Serialize};

use super::{Range, check_absolute, check_budget};

/// Command names, in axis order, as the agent sees them.
pub const AXIS_NAMES: [&str; 4] = [
    "mirror_1_axis_1",
    "mirror_1_axis_2",
    "mirror_2_axis_1",
    "mirror_2_axis_2",
];

/// Bounds and budget (`[tasks.michelson]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MichelsonLimits {
    /// Evaluations per run. Default 60.
    pub budget: usize,
    /// Absolute range per axis, in `AXIS_NAMES` order. Default +-8192 (axis 1), +-6144 (axis 2).
    pub ranges: [Range; 4],
    /// A run counts as a success when its terminal error is at most this, px. Default 50
    /// (our choice: the paper reports errors, not a success rule, for this task).
    pub success_error_px: f64,
}

impl Default for MichelsonLimits {
    fn default() -> Self {
        Self {
            budget: 60,
            ranges: [
                Range::symmetric(8192),
                Range::symmetric(6144),
                Range::symmetric(8192),
                Range::symmetric(6144),
            ],
            success_error_px: 50.0,
        }
    }
}

impl MichelsonLimits {
    pub fn validate(&self) -> Result<(), String> {
        check_budget("tasks.michelson.budget", self.budget)?;
        for (name, range) in AXIS_NAMES.iter().zip(&self.ranges) {
            if range.min > 0 || range.max < 0 {
                return Err(format!(
                    "tasks.michelson.ranges ({name}): {range} must contain the start setting 0"
                ));
            }
        }
        Ok(())
    }

    pub fn check(&self, command: &[i32; 4]) -> Result<(), String> {
        check_absolute(&AXIS_NAMES, &self.ranges, command)
    }
}

/// The score of a Michelson state.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct MichelsonScore {
    /// Summed distance of the true beam centres from the image centre, px.
    pub error_px: f64,
    /// The paper's variant: beam centres from the commanded positions through the linear
    /// calibration (ignores backlash and lost steps), px.
    pub commanded_error_px: f64,
    pub beam_centres_px: [[f64; 2]; 2],
}
