//! Axis configuration: defaults and the ranges a configuration must respect.
//!
//! The ranges also bound the integer arithmetic of the step timing (see [`crate::ramp`]):
//! positions within ±[`POSITION_RANGE`] keep a move under 2^26 motor steps, and
//! `max_speed / acceleration` under 2000 s keeps every squared time in a `u64`.

use core::ops::RangeInclusive;

use optalign_protocol::error_reply;
use optalign_protocol::{
    Approach, AxisConfig, BacklashMode, Capabilities, DriverKind, ErrorCode, ErrorReply, SoftLimits,
};

/// Soft limits (and so every logical position) lie within ±this many steps.
pub const POSITION_RANGE: i32 = 1 << 24;

/// Accepted cruise speeds, steps per second.
pub const MAX_SPEED: RangeInclusive<u32> = 1..=20_000;

/// Accepted accelerations, steps per second squared.
pub const ACCELERATION: RangeInclusive<u32> = 10..=500_000;

/// Largest backlash and largest overshoot margin, steps.
pub const MAX_BACKLASH: u16 = 2000;

/// The configuration of an axis nobody has configured yet.
///
/// 800 half-steps/s and 2000 steps/s² are well inside what a 28BYJ-48 on 5 V follows
/// reliably; limits of ±100000 steps are about ±24 output revolutions.
pub fn default_config(capabilities: Capabilities) -> AxisConfig {
    let driver = if capabilities.has(Capabilities::STEP_DIR)
        && !capabilities.has(Capabilities::UNIPOLAR_HALF_STEP)
    {
        DriverKind::StepDir
    } else {
        DriverKind::UnipolarHalfStep
    };
    AxisConfig {
        max_speed: 800,
        acceleration: 2000,
        backlash: 0,
        backlash_mode: BacklashMode::OneSided,
        approach: Approach::Positive,
        overshoot_margin: 10,
        limits: SoftLimits {
            min: -100_000,
            max: 100_000,
        },
        invert: false,
        idle_power_down_ms: 500,
        driver,
    }
}

/// Checks every field, naming the first one out of range.
pub fn validate(
    axis: u8,
    config: &AxisConfig,
    capabilities: Capabilities,
) -> Result<(), ErrorReply> {
    let invalid = ErrorCode::INVALID_CONFIG;
    if !MAX_SPEED.contains(&config.max_speed) {
        return Err(error_reply!(
            invalid,
            "axis {axis}: max_speed {} outside {}..={} steps/s",
            config.max_speed,
            MAX_SPEED.start(),
            MAX_SPEED.end()
        ));
    }
    if !ACCELERATION.contains(&config.acceleration) {
        return Err(error_reply!(
            invalid,
            "axis {axis}: acceleration {} outside {}..={} steps/s^2",
            config.acceleration,
            ACCELERATION.start(),
            ACCELERATION.end()
        ));
    }
    if config.backlash > MAX_BACKLASH {
        return Err(error_reply!(
            invalid,
            "axis {axis}: backlash {} above {MAX_BACKLASH} steps",
            config.backlash
        ));
    }
    if config.overshoot_margin > MAX_BACKLASH {
        return Err(error_reply!(
            invalid,
            "axis {axis}: overshoot_margin {} above {MAX_BACKLASH} steps",
            config.overshoot_margin
        ));
    }
    let SoftLimits { min, max } = config.limits;
    if min > max || min < -POSITION_RANGE || max > POSITION_RANGE {
        return Err(error_reply!(
            invalid,
            "axis {axis}: limits {min}..={max} must be ordered and within +-{POSITION_RANGE}"
        ));
    }
    let needed = match config.driver {
        DriverKind::UnipolarHalfStep => Capabilities::UNIPOLAR_HALF_STEP,
        DriverKind::StepDir => Capabilities::STEP_DIR,
    };
    if !capabilities.has(needed) {
        return Err(error_reply!(
            invalid,
            "axis {axis}: driver {:?} not supported by this board",
            config.driver
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const ALL: Capabilities =
        Capabilities(Capabilities::UNIPOLAR_HALF_STEP | Capabilities::STEP_DIR);

    #[test]
    fn default_is_valid() {
        assert_eq!(validate(0, &default_config(ALL), ALL), Ok(()));
        let step_dir = Capabilities(Capabilities::STEP_DIR);
        assert_eq!(validate(0, &default_config(step_dir), step_dir), Ok(()));
    }

    #[test]
    fn errors_name_axis_and_field() {
        let mut config = default_config(ALL);
        config.acceleration = 0;
        let error = validate(3, &config, ALL).unwrap_err();
        assert_eq!(error.code, ErrorCode::INVALID_CONFIG);
        assert!(error.reason.contains("axis 3: acceleration 0"), "{error}");

        let mut config = default_config(ALL);
        config.limits = SoftLimits { min: 5, max: 4 };
        assert!(
            validate(0, &config, ALL)
                .unwrap_err()
                .reason
                .contains("limits 5..=4")
        );

        let config = AxisConfig {
            driver: DriverKind::StepDir,
            ..default_config(ALL)
        };
        let half_step_only = Capabilities(Capabilities::UNIPOLAR_HALF_STEP);
        assert!(
            validate(0, &config, half_step_only)
                .unwrap_err()
                .reason
                .contains("StepDir")
        );
    }
}
