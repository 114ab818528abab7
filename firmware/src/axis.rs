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

    /// Makes one motor step in `travel`; returns what the driver must do.
    pub fn step(&mut self, travel: Travel) -> (StepDirection, i32) {
        if self.gear.step(travel, effective_backlash(&self.config)) {
            self.position = self.position.saturating_add(travel.sign());
        }
        self.motor_steps = self.motor_steps.wrapping_add(travel.sign());
        let direction = match (travel, self.config.invert) {
            (Travel::Positive, false) | (Travel::Negative, true) => StepDirection::Forward,
            (Travel::Negative, false) | (Travel::Positive, true) => StepDirection::Backward,
        };
        let delta = match direction {
            StepDirection::Forward => 1,
            StepDirection::Backward => -1,
        };
        self.coil_steps = self.coil_steps.wrapping_add(delta);
        (direction, self.coil_steps)
    }
}
