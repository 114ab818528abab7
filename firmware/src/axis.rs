//! The live state of one axis: configuration, positions, gear train, faults and power.

use optalign_protocol::{AxisConfig, Faults};

use crate::config::POSITION_RANGE;
use crate::driver::StepDirection;
use crate::gear::{Gear, Travel};
use crate::path::effective_backlash;
use crate::record::AxisRecord;

pub struct Axis {
    /// The configuration in force.
    pub config: AxisConfig,
    /// The configuration as last saved (what the record holds).
    pub saved: AxisConfig,
    /// Logical position: where the load is believed to be.
    pub position: i32,
    /// Every step made, in the logical sense.
    pub motor_steps: i32,
    /// Every step made, in the physical sense (what the coils see).
    pub coil_steps: i32,
    pub gear: Gear,
    pub faults: Faults,
    pub powered: bool,
    /// When idle coils are to be released.
    pub power_down_at: Option<u64>,
    /// Coils to be released at the next poll (emergency stop).
    pub cut_pending: bool,
    /// When this axis last stepped.
    pub last_step_us: u64,
}

impl Axis {
    pub fn new(config: AxisConfig) -> Self {
        Self {
            config,
            saved: config,
            position: 0,
            motor_steps: 0,
            coil_steps: 0,
            gear: Gear::UNKNOWN,
            faults: Faults::default(),
            powered: false,
            power_down_at: None,
            cut_pending: false,
            last_step_us: 0,
        }
    }

    /// An axis as saved; `config` is the record's configuration if it is valid, else the
    /// default. A position outside the representable range is reset and flagged lost.
    pub fn restore(record: &AxisRecord, config: AxisConfig) -> Self {
        let mut axis = Self::new(config);
        if (-POSITION_RANGE..=POSITION_RANGE).contains(&record.position) {
            axis.position = record.position;
            axis.gear = Gear::restore(record.slack, record.band, effective_backlash(&config));
        } else {
            axis.faults.0 |= Faults::POSITION_LOST;
        }
        axis.motor_steps = record.motor_steps;
        axis.coil_steps = record.coil_steps;
        axis
    }

    /// The saved state; the gear model is described for the saved configuration, which is
    /// the one it is restored with.
    pub fn record(&self) -> AxisRecord {
        let gear = self.gear.rebase(
            effective_backlash(&self.config),
            effective_backlash(&self.saved),
        );
        AxisRecord {
            config: self.saved,
            position: self.position,
            motor_steps: self.motor_steps,
            coil_steps: self.coil_steps,
            slack: gear.slack(),
            band: gear.band(),
        }
    }

    /// Replaces the configuration in force, keeping the gear model consistent.
    pub fn set_config(&mut self, config: AxisConfig) {
        let (old, new) = (
            effective_backlash(&self.config),
            effective_backlash(&config),
        );
        self.gear = self.gear.rebase(old, new);
        self.config = config;
    }

    /// Makes `count` motor steps in `travel` at once, exactly as `count` calls of
    /// [`Self::step`] would; returns the direction and the coil counter after the last.
    pub fn steps(&mut self, travel: Travel, count: u32) -> (StepDirection, i32) {
        let (gear, load) = self
            .gear
            .advance(travel, count, effective_backlash(&self.config));
        self.gear = gear;
        let load = i32::try_from(load).unwrap_or(i32::MAX);
        self.position = self
            .position
            .saturating_add(load.saturating_mul(travel.sign()));
        // The counters wrap, so `count as i32` (modular) is exact.
        let turned = (count as i32).wrapping_mul(travel.sign());
        self.motor_steps = self.motor_steps.wrapping_add(turned);
        let direction = self.direction(travel);
        self.coil_steps = self
            .coil_steps
            .wrapping_add((count as i32).wrapping_mul(direction.sign()));
        (direction, self.coil_steps)
    }

    /// The sense the motor turns for `travel`, after the axis's inversion.
    fn direction(&self, travel: Travel) -> StepDirection {
        match (travel, self.config.invert) {
            (Travel::Positive, false) | (Travel::Negative, true) => StepDirection::Forward,
            (Travel::Negative, false) | (Travel::Positive, true) => StepDirection::Backward,
        }
    }

    /// Makes one motor step in `travel`; returns what the driver must do.
    pub fn step(&mut self, travel: Travel) -> (StepDirection, i32) {
        if self.gear.step(travel, effective_backlash(&self.config)) {
            self.position = self.position.saturating_add(travel.sign());
        }
        self.motor_steps = self.motor_steps.wrapping_add(travel.sign());
        let direction = self.direction(travel);
        self.coil_steps = self.coil_steps.wrapping_add(direction.sign());
        (direction, self.coil_steps)
    }
}

#[cfg(test)]
mod tests {
    use optalign_protocol::{BacklashMode, Capabilities};
    use proptest::prelude::*;

    use super::*;
    use crate::config::default_config;

    fn axis(backlash: u16, invert: bool) -> Axis {
        Axis::new(AxisConfig {
            backlash,
            backlash_mode: BacklashMode::OneSided,
            invert,
            ..default_config(Capabilities(Capabilities::UNIPOLAR_HALF_STEP))
        })
    }

    proptest! {
        /// A run taken whole leaves the axis exactly as the same steps one by one do,
        /// whatever came before (the gear's slack, counters near their wrap).
        #[test]
        fn steps_at_once_equal_steps_one_by_one(
            backlash in 0u16..60,
            invert: bool,
            before in prop::collection::vec((any::<bool>(), 0u32..90), 0..4),
            positive: bool,
            count in 0u32..400,
            counters in prop_oneof![Just(0i32), Just(i32::MAX - 100), Just(i32::MIN + 100)],
        ) {
            let mut stepped = axis(backlash, invert);
            stepped.motor_steps = counters;
            stepped.coil_steps = counters;
            for &(up, n) in &before {
                let travel = if up { Travel::Positive } else { Travel::Negative };
                for _ in 0..n {
                    stepped.step(travel);
                }
            }
            let mut whole = axis(backlash, invert);
            whole.motor_steps = stepped.motor_steps;
            whole.coil_steps = stepped.coil_steps;
            whole.position = stepped.position;
            whole.gear = stepped.gear;
            let travel = if positive { Travel::Positive } else { Travel::Negative };
            let mut last = (whole.direction(travel), stepped.coil_steps);
            for _ in 0..count {
                last = stepped.step(travel);
            }
            prop_assert_eq!(whole.steps(travel, count), last);
            prop_assert_eq!(
                (whole.position, whole.motor_steps, whole.coil_steps, whole.gear),
                (stepped.position, stepped.motor_steps, stepped.coil_steps, stepped.gear)
            );
        }
    }
}
