//! Timestamped pin patterns: the core's step output as it appears on an axis's four pins.
//!
//! [`EventSink`] is the [`StepDriver`] the motion task hands to `Controller::poll`. The
//! motion task polls at each deadline exactly and tells the sink that time first, so every
//! step and every coil power change becomes an [`Event`] with its exact time, played on
//! the axis's timeline by the step engine the sink owns ([`StepEngine`]).
//!
//! An axis has four consecutive GPIOs; what they carry depends on its configured driver:
//! - ULN2003 (`UnipolarHalfStep`): IN1..IN4 = the half-step coil pattern; all low = off.
//! - STEP/DIR: bit 0 STEP, bit 1 DIR (high = forward), bit 2 EN (active low, so high =
//!   coils off), bit 3 unused (low). A step is a [`PULSE_US`] high pulse on STEP, with DIR
//!   settled [`SETUP_US`] before it; the step engine makes both from one pulse event.

use optalign_protocol::DriverKind;
use portable_atomic::{AtomicU32, AtomicU64, Ordering};

use super::pio_steps::StepEngine;
use super::{AXES, Store};
use crate::Controller;
use crate::driver::{StepDirection, StepDriver, half_step_coils};

/// STEP/DIR pin bits.
pub const STEP: u8 = 0b0001;
pub const DIR: u8 = 0b0010;
pub const DISABLE: u8 = 0b0100;

/// STEP pulse width and DIR set-up time (A4988 needs 1 µs and 0.2 µs, DRV8825 1.9 µs and
/// 0.65 µs, TMC2208 0.1 µs and 0.02 µs).
pub const PULSE_US: u64 = 2;
pub const SETUP_US: u64 = 2;

/// One change of an axis's pins.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Event {
    /// When, in microseconds since boot.
    pub at_us: u64,
    /// The four pin levels (bit 0 = the axis's first pin).
    pub pattern: u8,
    /// A STEP/DIR step: STEP goes high at `at_us` and low [`PULSE_US`] later.
    pub pulse: bool,
}

/// The time of the latest event queued: every axis is at rest once it has passed.
pub static LAST_EVENT_US: AtomicU64 = AtomicU64::new(0);

/// Step engine words dropped because an axis's ring was full (a bug if it ever counts).
pub static DROPPED: AtomicU32 = AtomicU32::new(0);

/// What the sink knows about one axis.
#[derive(Clone, Copy)]
struct AxisPins {
    kind: Option<DriverKind>,
    powered: bool,
    coil_steps: i32,
    forward: bool,
}

impl AxisPins {
    /// The pins at rest in the current state.
    fn pattern(&self) -> u8 {
        match self.kind {
            Some(DriverKind::StepDir) => {
                let dir = if self.forward { DIR } else { 0 };
                let enable = if self.powered { 0 } else { DISABLE };
                dir | enable
            }
            Some(DriverKind::UnipolarHalfStep) | None if self.powered => {
                half_step_coils(self.coil_steps)
            }
            Some(DriverKind::UnipolarHalfStep) | None => 0,
        }
    }
}

/// Turns the core's steps and power changes into events on the step engine.
pub struct EventSink {
    at_us: u64,
    axes: [AxisPins; AXES as usize],
    engine: StepEngine,
}

impl EventSink {
    pub fn new(engine: StepEngine) -> Self {
        Self {
            at_us: 0,
            axes: [AxisPins {
                kind: None,
                powered: false,
                coil_steps: 0,
                forward: true,
            }; AXES as usize],
            engine,
        }
    }

    /// The step engine, for the motion task's round (underruns, hand-over).
    pub fn engine(&mut self) -> &mut StepEngine {
        &mut self.engine
    }

    /// Sets the time of what the coming poll outputs, and takes each axis's driver kind
    /// from the core; an axis seen for the first time, or whose kind changed, gets its
    /// pins set for the current state (at start-up: coils off).
    pub fn prepare(&mut self, at_us: u64, core: &Controller<Store>) {
        self.at_us = at_us;
        for axis in 0..AXES {
            let kind = core.axis_config(axis).map(|c| c.driver);
            let Some(state) = self.axes.get_mut(usize::from(axis)) else {
                continue;
            };
            if kind.is_some() && state.kind != kind {
                state.kind = kind;
                let pattern = state.pattern();
                self.push(axis, pattern, false);
            }
        }
    }

    fn push(&mut self, axis: u8, pattern: u8, pulse: bool) {
        let event = Event {
            at_us: self.at_us,
            pattern,
            pulse,
        };
        self.engine.play(axis, event);
        LAST_EVENT_US.fetch_max(self.at_us, Ordering::Release);
    }
}

impl StepDriver for EventSink {
    fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32) {
        let Some(state) = self.axes.get_mut(usize::from(axis)) else {
            return;
        };
        state.coil_steps = motor_steps;
        state.forward = direction == StepDirection::Forward;
        let pattern = state.pattern();
        match state.kind {
            Some(DriverKind::StepDir) => self.push(axis, pattern | STEP, true),
            Some(DriverKind::UnipolarHalfStep) | None => self.push(axis, pattern, false),
        }
    }

    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32) {
        let Some(state) = self.axes.get_mut(usize::from(axis)) else {
            return;
        };
        state.powered = on;
        state.coil_steps = motor_steps;
        let pattern = state.pattern();
        self.push(axis, pattern, false);
    }
}
