//! Backlash compensation: the motor travel that brings the load to a logical target.
//!
//! A path is at most two legs of motor travel, each in one direction. Every leg's step
//! count includes the take-up of the gear train's dead band given its believed state
//! ([`Gear`]), so the load (the logical position) travels exactly the planned distance:
//!
//! - `Off`: one leg, no take-up (the configured backlash is ignored).
//! - `TakeUp`: one leg; on a reversal it starts with `backlash` slack steps.
//! - `OneSided`: every move ends travelling in the `approach` direction. A move arriving
//!   from the other side (or starting with the slack unknown, or a zero move while the gear
//!   train rests against the wrong contact) first goes `backlash + overshoot_margin` past
//!   the target, against the approach, then comes back: the return leg takes up the band
//!   and pushes the load onto the target. Because every move ends pressing the approach
//!   contact, the load lands exactly on target for any true dead band up to what the
//!   return leg covers (`2·backlash + margin` motor steps), which also makes moves smaller
//!   than the backlash exact.
//!
//! Soft limits: the overshoot point is clamped to the soft limits (widened to include the
//! current position), so the logical position never leaves them; only take-up steps, at
//! most `backlash`, turn the motor beyond the load. At a limit the excursion shrinks, down
//! to a return leg of take-up only, which still ends pressing the approach contact when the
//! configured backlash covers the true dead band.

use heapless::Vec;
use optalign_protocol::{AxisConfig, BacklashMode, Slack};

use crate::gear::{Gear, Travel};

/// Most legs in one axis's path.
pub const MAX_LEGS: usize = 2;

/// Motor travel in one direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Segment {
    pub travel: Travel,
    pub motor_steps: u32,
}

/// The legs of one axis's move, in order.
pub type Path = Vec<Segment, MAX_LEGS>;

/// The backlash the gear model works with: none when compensation is off.
pub fn effective_backlash(config: &AxisConfig) -> u16 {
    match config.backlash_mode {
        BacklashMode::Off => 0,
        BacklashMode::OneSided | BacklashMode::TakeUp => config.backlash,
    }
}

/// The motor travel that moves the load from `position` to `target`.
pub fn plan_path(gear: Gear, position: i32, target: i32, config: &AxisConfig) -> Path {
    let backlash = effective_backlash(config);
    let mut legs = Legs {
        path: Path::new(),
        gear,
        backlash,
    };
    let (position, target) = (i64::from(position), i64::from(target));
    let distance = (target - position).abs();
    let known = gear.slack() != Slack::Unknown;
    match config.backlash_mode {
        BacklashMode::OneSided => {
            let approach = Travel::from(config.approach);
            if known && Travel::of(target - position) == Some(approach) {
                legs.push(approach, distance, false);
            } else if !(known && distance == 0 && gear.is_engaged(approach, backlash)) {
                let excursion = i64::from(backlash) + i64::from(config.overshoot_margin);
                let low = i64::from(config.limits.min).min(position);
                let high = i64::from(config.limits.max).max(position);
                let far = match approach {
                    Travel::Positive => position.min(target) - excursion,
                    Travel::Negative => position.max(target) + excursion,
                }
                .clamp(low, high);
                legs.push(approach.reverse(), (position - far).abs(), false);
                legs.push(approach, (target - far).abs(), true);
            }
        }
        BacklashMode::TakeUp | BacklashMode::Off => {
            if let Some(travel) = Travel::of(target - position) {
                legs.push(travel, distance, false);
            }
        }
    }
    legs.path
}

/// A path under construction, with the gear state at its end.
struct Legs {
    path: Path,
    gear: Gear,
    backlash: u16,
}

impl Legs {
    /// Appends a leg moving the load `distance` steps; a zero-distance leg is kept only when
    /// `take_up_anyway` (the final OneSided leg must end against the approach contact).
    fn push(&mut self, travel: Travel, distance: i64, take_up_anyway: bool) {
        if distance == 0 && !take_up_anyway {
            return;
        }
        let load = u32::try_from(distance).unwrap_or(u32::MAX);
        let take_up = self.gear.take_up(travel, self.backlash);
        let motor_steps = load.saturating_add(u32::from(take_up));
        if motor_steps == 0 {
            return;
        }
        self.gear = self.gear.advance(travel, motor_steps, self.backlash).0;
        // At most two legs are ever pushed, the capacity of a Path.
        let _ = self.path.push(Segment {
            travel,
            motor_steps,
        });
    }
}

#[cfg(test)]
mod tests {
    use optalign_protocol::{Approach, Capabilities, SoftLimits};

    use super::*;
    use crate::config::default_config;

    fn config(mode: BacklashMode, backlash: u16) -> AxisConfig {
        AxisConfig {
            backlash,
            backlash_mode: mode,
            overshoot_margin: 10,
            ..default_config(Capabilities(Capabilities::UNIPOLAR_HALF_STEP))
        }
    }

    fn seg(travel: Travel, motor_steps: u32) -> Segment {
        Segment {
            travel,
            motor_steps,
        }
    }

    use Travel::{Negative as Neg, Positive as Pos};

    fn engaged(travel: Travel, backlash: u16) -> Gear {
        match travel {
            Pos => Gear::restore(Slack::TakenUpPositive, backlash, backlash),
            Neg => Gear::restore(Slack::TakenUpNegative, 0, backlash),
        }
    }

    #[test]
    fn one_sided_from_the_preferred_side_is_direct() {
        let c = config(BacklashMode::OneSided, 40);
        assert_eq!(plan_path(engaged(Pos, 40), 0, 100, &c), [seg(Pos, 100)]);
        assert_eq!(plan_path(engaged(Neg, 40), 0, 3, &c), [seg(Pos, 43)]);
        assert!(plan_path(engaged(Pos, 40), 7, 7, &c).is_empty());
    }

    #[test]
    fn one_sided_from_the_wrong_side_overshoots_and_returns() {
        let c = config(BacklashMode::OneSided, 40);
        // -5: 40 slack + 5 + 50 past, then 40 slack + 50 back.
        assert_eq!(
            plan_path(engaged(Pos, 40), 0, -5, &c),
            [seg(Neg, 95), seg(Pos, 90)]
        );
        // A zero move resting on the wrong contact re-seats on the approach side.
        assert_eq!(
            plan_path(engaged(Neg, 40), 0, 0, &c),
            [seg(Neg, 50), seg(Pos, 90)]
        );
        let negative = AxisConfig {
            approach: Approach::Negative,
            ..c
        };
        assert_eq!(
            plan_path(engaged(Neg, 40), 0, 5, &negative),
            [seg(Pos, 95), seg(Neg, 90)]
        );
    }

    #[test]
    fn one_sided_with_unknown_slack_always_overshoots() {
        let c = config(BacklashMode::OneSided, 40);
        assert_eq!(
            plan_path(Gear::UNKNOWN, 0, 3, &c),
            [seg(Neg, 90), seg(Pos, 93)]
        );
        assert_eq!(
            plan_path(Gear::UNKNOWN, 0, 0, &c),
            [seg(Neg, 90), seg(Pos, 90)]
        );
    }

    #[test]
    fn overshoot_is_clamped_to_the_soft_limits() {
        let c = AxisConfig {
            limits: SoftLimits { min: -20, max: 100 },
            ..config(BacklashMode::OneSided, 40)
        };
        assert_eq!(
            plan_path(engaged(Pos, 40), 0, -5, &c),
            [seg(Neg, 60), seg(Pos, 55)]
        );
        // Target on the limit: the return leg is take-up only.
        assert_eq!(
            plan_path(engaged(Pos, 40), 0, -20, &c),
            [seg(Neg, 60), seg(Pos, 40)]
        );
        // Already outside the limits (they were narrowed): never travel further out.
        assert_eq!(plan_path(engaged(Pos, 40), -30, -25, &c), [seg(Pos, 5)]);
        assert_eq!(plan_path(engaged(Pos, 40), -30, -30, &c), []);
        assert_eq!(plan_path(engaged(Neg, 40), -30, -30, &c), [seg(Pos, 40)]);
    }

    #[test]
    fn take_up_inserts_slack_on_reversal_only() {
        let c = config(BacklashMode::TakeUp, 25);
        assert_eq!(plan_path(engaged(Pos, 25), 0, 10, &c), [seg(Pos, 10)]);
        assert_eq!(plan_path(engaged(Pos, 25), 0, -10, &c), [seg(Neg, 35)]);
        assert_eq!(plan_path(Gear::UNKNOWN, 0, -10, &c), [seg(Neg, 35)]);
        assert!(plan_path(engaged(Neg, 25), 4, 4, &c).is_empty());
    }

    #[test]
    fn off_ignores_backlash() {
        let c = config(BacklashMode::Off, 25);
        assert_eq!(plan_path(engaged(Pos, 25), 0, -10, &c), [seg(Neg, 10)]);
        assert_eq!(plan_path(Gear::UNKNOWN, 0, 10, &c), [seg(Pos, 10)]);
    }
}
