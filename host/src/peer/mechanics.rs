//! Simulated mount mechanics: what happens between the motor's steps and the mirror.
//!
//! Each axis gets a mount model from the firmware crate's `sim` module (gear dead band,
//! lost steps, a binding region); its driver receives the firmware core's steps and holds
//! the true shaft positions the scenes read.

use optalign_firmware::sim::{MountModel, SimDriver};
use serde::{Deserialize, Serialize};

/// A range of true shaft positions where the screw binds and steps are lost.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct StallRegion {
    pub axis: u8,
    pub from: i32,
    pub to: i32,
    /// Chance that a step into the region is lost (1 = a hard stop).
    pub probability: f32,
}

/// Mechanical imperfections of the simulated mounts.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct MechanicsOptions {
    /// True gear/screw dead band of every axis, in steps.
    pub backlash: u32,
    /// Probability that any one step is lost (the shaft does not follow).
    pub lost_step_probability: f64,
    /// Regions where the mount binds.
    pub stalls: Vec<StallRegion>,
    /// Amplitude of the screws' periodic pitch error, steps.
    #[serde(default)]
    pub pitch_error: u32,
    /// Period of the pitch error, steps.
    #[serde(default)]
    pub pitch_period: u32,
    /// Elastic hysteresis of the screws beyond the dead band, steps either side.
    #[serde(default)]
    pub hysteresis: u32,
    /// Seed for the lost-step generators (deterministic runs).
    pub seed: u64,
}

impl MechanicsOptions {
    /// The driver with one mount per axis.
    pub fn driver(&self, axes: u8) -> SimDriver {
        SimDriver::new((0..axes).map(|axis| self.mount(axis)))
    }

    fn mount(&self, axis: u8) -> MountModel {
        let mut model = MountModel::new(self.backlash)
            .with_seed(self.seed ^ (u64::from(axis) + 1).wrapping_mul(0x9e37_79b9_7f4a_7c15))
            .with_lost_steps(self.lost_step_probability as f32)
            .with_screw(self.pitch_error, self.pitch_period, self.hysteresis);
        for stall in self.stalls.iter().filter(|s| s.axis == axis) {
            model = model.with_stall_region(stall.from, stall.to, stall.probability);
        }
        model
    }
}
