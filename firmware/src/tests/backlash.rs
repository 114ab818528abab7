//! Backlash compensation end to end: the simulated mount's true load position against the
//! logical position.

use optalign_protocol::{
    Approach, AxisConfig, BacklashMode, Capabilities, Command, MoveOutcome, Reply, Slack,
    SoftLimits,
};
use proptest::prelude::*;

use super::rig::{Rig, values};
use crate::RamStorage;
use crate::config::default_config;
use crate::record::{AxisRecord, Record};
use crate::sim::MountModel;
use crate::slots::Journal;

fn config(mode: BacklashMode, backlash: u16, margin: u16, approach: Approach) -> AxisConfig {
    AxisConfig {
        max_speed: 5000,
        acceleration: 50_000,
        backlash,
        backlash_mode: mode,
        approach,
        overshoot_margin: margin,
        ..default_config(Capabilities(Capabilities::UNIPOLAR_HALF_STEP))
    }
}

/// One axis on a mount with dead band `true_backlash`, resting against `approach`'s contact;
/// the controller boots fresh (slack unknown).
fn rig(true_backlash: u32, config: AxisConfig) -> Rig {
    rig_from(RamStorage::new(), true_backlash, config)
}

fn rig_from(storage: RamStorage, true_backlash: u32, config: AxisConfig) -> Rig {
    let play = match config.approach {
        Approach::Positive => true_backlash,
        Approach::Negative => 0,
    };
    let mut rig = Rig::boot(storage, [MountModel::new(true_backlash).with_play(play)], 1);
    rig.ok(Command::SetConfig { axis: 0, config });
    rig
}

/// Storage whose record says the gear train rests pressed in the positive direction.
fn pressed_positive(config: AxisConfig) -> RamStorage {
    let mut storage = RamStorage::new();
    let record = Record {
        axes: [AxisRecord {
            config,
            position: 0,
            motor_steps: 0,
            coil_steps: 0,
            slack: Slack::TakenUpPositive,
            band: config.backlash,
        }]
        .into_iter()
        .collect(),
        ..Record::default()
    };
    let (mut journal, _) = Journal::load(&mut storage);
    journal.save(&mut storage, &record).unwrap();
    storage
}

#[derive(Clone, Copy, Debug)]
enum Step {
    To(i32),
    By(i32),
    /// Move to a target, then Stop after this fraction of the planned time.
    StopDuring(i32, f64),
}

fn steps() -> impl Strategy<Value = Vec<Step>> {
    prop::collection::vec(
        prop_oneof![
            3 => (-3000i32..3000).prop_map(Step::To),
            3 => (-80i32..80).prop_map(Step::By),
            1 => ((-3000i32..3000), 0.0f64..1.0).prop_map(|(t, f)| Step::StopDuring(t, f)),
        ],
        100,
    )
}

/// Runs one step; returns the logical position afterwards.
fn run(rig: &mut Rig, step: Step, with_stops: bool) -> i32 {
    match step {
        Step::To(target) => {
            rig.move_to(&[(0, target)]);
        }
        Step::By(delta) => {
            rig.send(Command::MoveBy {
                deltas: values(&[(0, delta)]),
            });
        }
        Step::StopDuring(target, fraction) => {
            let Reply::MoveStarted { duration_ms } = rig.move_to(&[(0, target)]) else {
                panic!("move refused");
            };
            if with_stops {
                let at = rig.now + (f64::from(duration_ms) * 1000.0 * fraction) as u64;
                rig.run_until(at);
                rig.ok(Command::Stop);
            }
        }
    }
    rig.settle_fast();
    rig.position(0)
}

#[test]
fn small_moves_below_the_backlash_land_exactly() {
    // The case other firmwares get wrong: backlash 40, moves of a few steps.
    let mut rig = rig(
        40,
        config(BacklashMode::OneSided, 40, 10, Approach::Positive),
    );
    for (delta, expected) in [(-5, -5), (3, -2), (-1, -3), (2, -1), (0, -1), (-40, -41)] {
        rig.send(Command::MoveBy {
            deltas: values(&[(0, delta)]),
        });
        rig.settle_fast();
        assert_eq!(
            (rig.position(0), rig.shaft(0)),
            (expected, expected),
            "after {delta}"
        );
    }
    rig.move_and_settle(&[(0, -5)]);
    rig.move_and_settle(&[(0, 3)]);
    assert_eq!((rig.position(0), rig.shaft(0)), (3, 3));
}

#[test]
fn small_alternating_moves_with_take_up() {
    let mut rig = rig(30, config(BacklashMode::TakeUp, 30, 0, Approach::Positive));
    rig.move_and_settle(&[(0, 100)]);
    let offset = rig.shaft(0) - rig.position(0);
    for target in [95, 97, 96, 99, 98, 98, 120, 119] {
        rig.move_and_settle(&[(0, target)]);
        assert_eq!(rig.shaft(0) - rig.position(0), offset, "at {target}");
        assert_eq!(rig.position(0), target);
    }
}

#[test]
fn take_up_after_power_up_fixes_the_origin_with_the_first_move() {
    // Slack unknown: the first move takes up the whole band, which here (the gear train
    // was already pressed positive) moves the load 17 steps further, once.
    let mut rig = rig(17, config(BacklashMode::TakeUp, 17, 0, Approach::Positive));
    rig.move_and_settle(&[(0, 100)]);
    assert_eq!((rig.position(0), rig.shaft(0)), (100, 117));
    for target in [90, 95, 94, -300, 2, 1, 400] {
        rig.move_and_settle(&[(0, target)]);
        assert_eq!(rig.shaft(0), target + 17, "at {target}");
    }
}

#[test]
fn one_sided_overshoot_stays_inside_the_soft_limits() {
    let config = AxisConfig {
        limits: SoftLimits {
            min: -100,
            max: 100,
        },
        ..config(BacklashMode::OneSided, 40, 10, Approach::Positive)
    };
    let mut rig = rig(40, config);
    for target in [50, -90, 100, -100, 0, -100] {
        rig.move_and_settle(&[(0, target)]);
        assert_eq!((rig.position(0), rig.shaft(0)), (target, target));
    }
    // Replay the steps on an identical mount: the load never went past the limits.
    let mut mount = MountModel::new(40);
    let (mut lowest, mut highest) = (i32::MAX, i32::MIN);
    for step in &rig.driver.steps {
        mount.apply_step(step.direction);
        lowest = lowest.min(mount.shaft_position());
        highest = highest.max(mount.shaft_position());
    }
    assert_eq!((lowest, highest), (-100, 100));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]

    /// OneSided with a configured backlash at least the true one: every move ends with the
    /// load exactly on target, whatever the sequence (small moves and reversals included).
    #[test]
    fn one_sided_lands_exactly(
        true_backlash in 0u32..60,
        extra in 0u16..40,
        margin in 0u16..20,
        positive in any::<bool>(),
        steps in steps(),
    ) {
        let approach = if positive { Approach::Positive } else { Approach::Negative };
        let backlash = true_backlash as u16 + extra;
        let mut rig = rig(true_backlash, config(BacklashMode::OneSided, backlash, margin, approach));
        for step in steps {
            let position = run(&mut rig, step, false);
            prop_assert_eq!(rig.shaft(0), position, "after {:?}", step);
        }
    }

    /// With the configured backlash equal to the true one and the slack state known (here
    /// from the stored record), the model is exact at all times: stops in the middle of a
    /// compensation leave positions consistent.
    #[test]
    fn stops_leave_the_model_exact(
        backlash in 0u16..60,
        take_up in any::<bool>(),
        steps in steps(),
    ) {
        let mode = if take_up { BacklashMode::TakeUp } else { BacklashMode::OneSided };
        let config = config(mode, backlash, 10, Approach::Positive);
        let mut rig = rig_from(pressed_positive(config), u32::from(backlash), config);
        for step in steps {
            let position = run(&mut rig, step, true);
            prop_assert_eq!(rig.shaft(0), position, "after {:?}", step);
        }
        prop_assert!(rig.finished().iter().any(|f| f.1 == MoveOutcome::Stopped));
    }

    /// Without compensation the load lags the logical position by up to the dead band.
    #[test]
    fn without_compensation_the_error_is_the_dead_band(
        true_backlash in 1u32..60,
        steps in steps(),
    ) {
        let mut rig = rig(true_backlash, config(BacklashMode::Off, 0, 0, Approach::Positive));
        let mut worst = 0;
        for step in steps {
            let position = run(&mut rig, step, false);
            let error = (rig.shaft(0) - position).unsigned_abs();
            prop_assert!(error <= true_backlash);
            worst = worst.max(error);
        }
        prop_assert_eq!(worst, true_backlash);
    }
}
