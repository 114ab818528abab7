//! Motion end to end: coordination, timing, stops, replacement, emergency stop, coils.

use optalign_protocol::{
    Approach, AxisConfig, BacklashMode, Capabilities, Command, Direction, ErrorCode, Faults,
    MoveOutcome, MoveResult, Notification, Reply, RequestId,
};
use proptest::prelude::*;

use super::rig::{Rig, values};
use crate::StepDirection;
use crate::config::default_config;

/// OneSided compensation when `backlash` is given, none otherwise.
fn config(max_speed: u32, acceleration: u32, backlash: u16) -> AxisConfig {
    AxisConfig {
        max_speed,
        acceleration,
        backlash,
        backlash_mode: if backlash > 0 {
            BacklashMode::OneSided
        } else {
            BacklashMode::Off
        },
        ..default_config(Capabilities(Capabilities::UNIPOLAR_HALF_STEP))
    }
}

fn duration_ms(reply: &Reply) -> u64 {
    match reply {
        Reply::MoveStarted { duration_ms } => u64::from(*duration_ms),
        other => panic!("expected MoveStarted, got {other:?}"),
    }
}

/// Asserts the logged steps of `axis` never exceed `max_speed` (3 µs rounding per step).
fn assert_speed_within(rig: &Rig, axis: u8, max_speed: u32) {
    let min_interval = 1_000_000 / u64::from(max_speed);
    for pair in rig.steps_of(axis).windows(2) {
        if pair[0].direction == pair[1].direction {
            let interval = pair[1].at_us - pair[0].at_us;
            assert!(
                interval + 2 >= min_interval,
                "axis {axis}: {interval} µs between steps"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]

    /// All axes of a move make their last step at the same time (within one step), and no
    /// axis exceeds its own speed limit, whatever their limits and distances.
    #[test]
    fn coordinated_axes_finish_together(
        axes in prop::collection::vec(
            (-2000i32..2000, 100u32..3000, 500u32..20_000, 0u16..30), 2..4),
    ) {
        let count = axes.len() as u8;
        let mut rig = Rig::new(count, 0, config(800, 2000, 0));
        for (axis, &(_, speed, accel, backlash)) in (0u8..).zip(&axes) {
            rig.ok(Command::SetConfig { axis, config: config(speed, accel, backlash) });
        }
        let targets: Vec<(u8, i32)> = (0u8..).zip(axes.iter().map(|a| a.0)).collect();
        let start = rig.now;
        let reply = rig.move_to(&targets);
        rig.settle();
        let lasts: Vec<u64> = (0..count)
            .filter_map(|axis| rig.steps_of(axis).last().map(|s| s.at_us))
            .collect();
        let end = *lasts.iter().max().unwrap();
        for (axis, &(_, speed, ..)) in (0u8..).zip(&axes) {
            let Some(last) = rig.steps_of(axis).last().map(|s| s.at_us) else { continue };
            prop_assert!(end - last <= 1_000_000 / u64::from(speed), "axis {} ends at {} of {}", axis, last, end);
            assert_speed_within(&rig, axis, speed);
        }
        // The reply announced the duration.
        prop_assert_eq!(duration_ms(&reply), (end - start).div_ceil(1000));
        for (axis, &(target, ..)) in (0u8..).zip(&axes) {
            prop_assert_eq!(rig.position(axis), target);
        }
    }

    /// A host simulation polling in big strides gets exactly the same steps on each axis,
    /// in the same order, as a board polling at every deadline (it may take a whole run
    /// of one axis before the other's).
    #[test]
    fn late_polls_make_the_same_steps(
        moves in prop::collection::vec((-1500i32..1500, -1500i32..1500), 1..6),
    ) {
        let mut fine = Rig::new(2, 10, config(2000, 8000, 10));
        let mut coarse = Rig::new(2, 10, config(2000, 8000, 10));
        for &(a, b) in &moves {
            fine.move_to(&[(0, a), (1, b)]);
            fine.settle();
            coarse.move_to(&[(0, a), (1, b)]);
            coarse.settle_fast();
        }
        for axis in 0..2 {
            let directions = |rig: &Rig| rig.steps_of(axis).iter().map(|s| s.direction).collect::<Vec<_>>();
            prop_assert_eq!(directions(&fine), directions(&coarse));
        }
        prop_assert_eq!(fine.status().axes, coarse.status().axes);
        prop_assert_eq!(fine.finished().into_iter().map(|f| (f.1, f.2)).collect::<Vec<_>>(),
            coarse.finished().into_iter().map(|f| (f.1, f.2)).collect::<Vec<_>>());
    }
}

#[test]
fn long_move_ramps_up_cruises_and_ramps_down() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    let reply = rig.move_to(&[(0, 4096)]);
    assert_eq!(duration_ms(&reply), 5520);
    rig.settle();
    let steps = rig.steps_of(0);
    assert_eq!(steps.len(), 4096);
    let start = steps[0].at_us - 31_622;
    let interval = |k: usize| steps[k].at_us - steps[k - 1].at_us;
    assert_eq!(interval(2048), 1250);
    assert!(interval(1) > 10_000 && interval(4095) > 10_000);
    assert_eq!(steps[4095].at_us - start, 5_520_000);
    assert_speed_within(&rig, 0, 800);
}

#[test]
fn stop_brakes_along_the_ramp_and_reports_stopped() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    let reply = rig.send_id(
        RequestId(7),
        Command::MoveTo {
            targets: values(&[(0, 4000)]),
        },
    );
    assert!(matches!(reply, Reply::MoveStarted { .. }));
    rig.run_until(rig.now + 2_000_000);
    let before = rig.position(0);
    assert!(rig.status().axes[0].moving);
    assert_eq!(rig.status().axes[0].direction, Direction::Positive);
    assert_eq!(rig.status().axes[0].target, 4000);
    rig.ok(Command::Stop);
    rig.settle();
    let after = rig.position(0);
    // Braking from 800 steps/s at 2000 steps/s²: 160 steps.
    assert!(
        (159..=161).contains(&(after - before)),
        "{before} -> {after}"
    );
    assert_eq!(
        rig.finished(),
        [(RequestId(7), MoveOutcome::Stopped, vec![after])]
    );
    assert_speed_within(&rig, 0, 800);
    let status = rig.status();
    assert!(!status.axes[0].moving);
    assert_eq!(status.axes[0].target, after);
    // Stop when idle is fine.
    rig.ok(Command::Stop);
}

#[test]
fn a_new_move_replaces_the_running_one() {
    let mut rig = Rig::new(1, 20, config(800, 2000, 20));
    rig.send_id(
        RequestId(1),
        Command::MoveTo {
            targets: values(&[(0, 4000)]),
        },
    );
    rig.run_until(rig.now + 1_500_000);
    let asked = rig.now;
    let reply = rig.send_id(
        RequestId(2),
        Command::MoveTo {
            targets: values(&[(0, -300)]),
        },
    );
    let announced = duration_ms(&reply);
    // The running move brakes first, then the new one runs from where it stopped.
    let status = rig.status();
    assert_eq!(status.axes[0].target, -300);
    rig.settle();
    let finished = rig.finished();
    assert_eq!(finished.len(), 2);
    assert_eq!(
        (finished[0].0, finished[0].1),
        (RequestId(1), MoveOutcome::Stopped)
    );
    assert_eq!(
        finished[1],
        (RequestId(2), MoveOutcome::Completed, vec![-300])
    );
    assert_eq!(rig.shaft(0), -300);
    let end = rig.steps_of(0).last().unwrap().at_us;
    assert_eq!(announced, (end - asked).div_ceil(1000));
    assert_speed_within(&rig, 0, 800);
}

#[test]
fn a_move_after_an_unpolled_end_starts_now_not_in_the_past() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    rig.move_to(&[(0, 100)]);
    // The board was busy: the first move ran out long ago but nobody polled.
    rig.now += 10_000_000;
    let asked = rig.now;
    rig.move_to(&[(0, 300)]);
    rig.settle();
    let second: Vec<_> = rig.steps_of(0).into_iter().skip(100).collect();
    assert_eq!(second.len(), 200);
    assert!(second[0].at_us > asked);
    for pair in second.windows(2) {
        assert!(pair[1].at_us - pair[0].at_us + 3 >= 1_250);
    }
}

#[test]
fn move_by_during_motion_is_relative_to_where_it_comes_to_rest() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    rig.move_to(&[(0, 4000)]);
    rig.run_until(rig.now + 1_500_000);
    rig.ok(Command::Stop);
    rig.settle();
    let rest = rig.position(0);
    let mut other = Rig::new(1, 0, config(800, 2000, 0));
    other.move_to(&[(0, 4000)]);
    other.run_until(other.now + 1_500_000);
    other.send(Command::MoveBy {
        deltas: values(&[(0, 100)]),
    });
    other.settle();
    assert_eq!(other.position(0), rest + 100);
}

#[test]
fn a_move_waiting_for_a_stop_that_is_replaced_finishes_at_once() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    rig.send_id(
        RequestId(1),
        Command::MoveTo {
            targets: values(&[(0, 4000)]),
        },
    );
    rig.run_until(rig.now + 1_000_000);
    rig.send_id(
        RequestId(2),
        Command::MoveTo {
            targets: values(&[(0, 10)]),
        },
    );
    rig.send_id(
        RequestId(3),
        Command::MoveTo {
            targets: values(&[(0, 20)]),
        },
    );
    rig.settle();
    let outcomes: Vec<_> = rig.finished().into_iter().map(|f| (f.0, f.1)).collect();
    assert_eq!(
        outcomes,
        [
            (RequestId(2), MoveOutcome::Stopped),
            (RequestId(1), MoveOutcome::Stopped),
            (RequestId(3), MoveOutcome::Completed)
        ]
    );
    assert_eq!(rig.position(0), 20);
}

#[test]
fn emergency_stop_cuts_at_once_and_latches_until_cleared() {
    let mut rig = Rig::new(2, 0, config(800, 2000, 0));
    rig.send_id(
        RequestId(5),
        Command::MoveTo {
            targets: values(&[(0, 3000)]),
        },
    );
    rig.run_until(rig.now + 1_000_000);
    let steps_before = rig.driver.steps.len();
    rig.ok(Command::EmergencyStop);
    assert_eq!(rig.controller.next_deadline_us(), Some(rig.now));
    rig.poll();
    assert!(!rig.driver.sim.is_powered(0));
    assert_eq!(
        rig.driver.power.last().map(|p| (p.0, p.1)),
        Some((0, false))
    );
    rig.settle();
    assert_eq!(
        rig.driver.steps.len(),
        steps_before,
        "no step after the emergency stop"
    );
    let position = rig.position(0);
    assert_eq!(rig.shaft(0), position);
    assert_eq!(
        rig.notes[..2],
        [
            Notification::Fault {
                axis: 0,
                faults: Faults(Faults::EMERGENCY_STOP)
            },
            Notification::MoveFinished {
                request: RequestId(5),
                outcome: MoveOutcome::EmergencyStopped,
                positions: [position, 0].into_iter().collect(),
            },
        ]
    );
    let status = rig.status();
    assert!(status.emergency_stopped);
    assert!(status.axes[0].faults.has(Faults::EMERGENCY_STOP));
    assert!(status.axes[1].faults.is_clear());
    assert!(!status.axes[0].powered);
    // Moves are refused while latched, and nothing steps.
    let reason = rig.error(
        Command::MoveTo {
            targets: values(&[(0, 0)]),
        },
        ErrorCode::EMERGENCY_STOPPED,
    );
    assert!(reason.contains("ClearEmergency"), "{reason}");
    rig.settle();
    assert_eq!(rig.driver.steps.len(), steps_before);
    assert!(rig.status().emergency_stopped);
    // Cleared: the latch and the fault bits go, the coils stay off until the next move.
    rig.ok(Command::ClearEmergency);
    let status = rig.status();
    assert!(!status.emergency_stopped && status.axes[0].faults.is_clear());
    assert!(!status.axes[0].powered);
    rig.move_and_settle(&[(0, 0)]);
    assert_eq!(rig.shaft(0), 0);
    // An emergency stop when idle latches too.
    rig.ok(Command::EmergencyStop);
    assert!(rig.status().emergency_stopped);
}

#[test]
fn coils_power_up_before_stepping_and_down_when_idle() {
    let mut rig = Rig::new(2, 0, config(800, 2000, 0));
    rig.ok(Command::SetConfig {
        axis: 1,
        config: AxisConfig {
            idle_power_down_ms: 0,
            ..config(800, 2000, 0)
        },
    });
    assert!(!rig.status().axes[0].powered);
    rig.move_to(&[(0, 100), (1, 50)]);
    rig.run_until(rig.now);
    assert!(rig.status().axes[0].powered);
    rig.settle();
    assert_eq!(rig.driver.sim.unpowered_steps(), 0);
    let last = rig.steps_of(0).last().unwrap().at_us;
    // Axis 0 released 500 ms after its last step; axis 1 (0 ms) stays powered.
    let offs: Vec<_> = rig.driver.power.iter().filter(|p| !p.1).collect();
    assert_eq!(offs, [&(0, false, last + 500_000)]);
    assert!(!rig.status().axes[0].powered && rig.status().axes[1].powered);
    assert_eq!(rig.controller.next_deadline_us(), None);
    // The next move keeps axis 1's coils on and re-energises axis 0.
    rig.move_and_settle(&[(0, 0), (1, 0)]);
    let ons: Vec<_> = rig
        .driver
        .power
        .iter()
        .filter(|p| p.1)
        .map(|p| p.0)
        .collect();
    assert_eq!(ons, [0, 1, 0]);
}

#[test]
fn half_step_counter_and_invert() {
    let mut rig = Rig::new(2, 0, config(800, 2000, 0));
    rig.ok(Command::SetConfig {
        axis: 1,
        config: AxisConfig {
            invert: true,
            ..config(800, 2000, 0)
        },
    });
    rig.move_and_settle(&[(0, 10), (1, 10)]);
    assert!(
        rig.steps_of(0)
            .iter()
            .all(|s| s.direction == StepDirection::Forward)
    );
    assert!(
        rig.steps_of(1)
            .iter()
            .all(|s| s.direction == StepDirection::Backward)
    );
    assert_eq!(rig.driver.sim.coil_steps(0), 10);
    assert_eq!(rig.driver.sim.coil_steps(1), -10);
    let status = rig.status();
    assert_eq!(
        (status.axes[1].position, status.axes[1].motor_steps),
        (10, 10)
    );
}

#[test]
fn the_record_is_written_when_motion_stops_not_per_step() {
    let mut rig = Rig::new(1, 0, config(800, 2000, 0));
    let writes = rig.controller.storage().writes();
    rig.move_to(&[(0, 1000)]);
    rig.run_until(rig.now + 500_000);
    assert_eq!(rig.controller.storage().writes(), writes);
    rig.settle();
    assert_eq!(rig.controller.storage().writes(), writes + 1);
    // A move that changes nothing writes nothing.
    rig.move_and_settle(&[(0, 1000)]);
    assert_eq!(rig.controller.storage().writes(), writes + 1);
}

#[test]
fn busy_axes_refuse_configuration_and_position() {
    let mut rig = Rig::new(2, 0, config(800, 2000, 0));
    rig.move_to(&[(0, 1000)]);
    let reason = rig.error(
        Command::SetPosition {
            axis: 0,
            position: 0,
        },
        ErrorCode::BUSY,
    );
    assert!(reason.contains("axis 0"), "{reason}");
    rig.error(
        Command::SetConfig {
            axis: 0,
            config: config(800, 2000, 0),
        },
        ErrorCode::BUSY,
    );
    // The idle axis can be configured meanwhile.
    rig.ok(Command::SetPosition {
        axis: 1,
        position: 5,
    });
    rig.settle();
    rig.ok(Command::SetPosition {
        axis: 0,
        position: 0,
    });
    assert_eq!(rig.shaft(0), 1000);
}

#[test]
fn zero_and_empty_moves_complete() {
    let mut rig = Rig::new(
        1,
        0,
        AxisConfig {
            backlash_mode: BacklashMode::TakeUp,
            approach: Approach::Negative,
            ..config(800, 2000, 0)
        },
    );
    assert_eq!(duration_ms(&rig.move_to(&[])), 0);
    assert_eq!(duration_ms(&rig.move_to(&[(0, 0)])), 0);
    rig.settle();
    assert_eq!(rig.finished().len(), 2);
    assert!(rig.finished().iter().all(|f| f.1 == MoveOutcome::Completed));
    assert!(rig.driver.steps.is_empty());
}

#[test]
fn every_move_keeps_its_result_by_request_id() {
    let mut rig = Rig::new(2, 0, config(800, 2000, 0));
    let result = |rig: &mut Rig, id: u32| match rig.send(Command::MoveResult {
        request: RequestId(id),
    }) {
        Reply::MoveResult(result) => result,
        other => panic!("{other:?}"),
    };
    let finished = |outcome, positions: &[i32]| MoveResult::Finished {
        outcome,
        positions: positions.iter().copied().collect(),
    };
    let move_to = |targets: &[(u8, i32)]| Command::MoveTo {
        targets: values(targets),
    };
    assert_eq!(result(&mut rig, 1), MoveResult::Unknown);
    // Running, then stopped: the result says so (the axis is idle at its stop position,
    // where position and target agree).
    rig.send_id(RequestId(1), move_to(&[(0, 3000)]));
    rig.run_until(rig.now + 500_000);
    assert_eq!(result(&mut rig, 1), MoveResult::InProgress);
    rig.ok(Command::Stop);
    rig.settle();
    let stopped_at = rig.position(0);
    assert!(stopped_at > 0 && stopped_at < 3000, "{stopped_at}");
    assert_eq!(
        result(&mut rig, 1),
        finished(MoveOutcome::Stopped, &[stopped_at, 0])
    );
    let status = rig.status();
    assert!(status.axes.iter().all(|a| a.target == a.position));
    // Completed.
    rig.send_id(RequestId(2), move_to(&[(1, 40)]));
    rig.settle();
    assert_eq!(
        result(&mut rig, 2),
        finished(MoveOutcome::Completed, &[stopped_at, 40])
    );
    // A move waiting for another to brake, replaced before it began.
    rig.send_id(RequestId(3), move_to(&[(0, 0)]));
    rig.run_until(rig.now + 300_000);
    rig.send_id(RequestId(4), move_to(&[(1, 0)]));
    rig.send_id(RequestId(5), move_to(&[(1, 80)]));
    assert!(matches!(
        result(&mut rig, 4),
        MoveResult::Finished {
            outcome: MoveOutcome::Stopped,
            ..
        }
    ));
    rig.settle();
    assert!(matches!(
        result(&mut rig, 3),
        MoveResult::Finished {
            outcome: MoveOutcome::Stopped,
            ..
        }
    ));
    assert!(matches!(
        result(&mut rig, 5),
        MoveResult::Finished {
            outcome: MoveOutcome::Completed,
            ..
        }
    ));
    // Emergency-stopped.
    rig.send_id(RequestId(6), move_to(&[(0, 2000)]));
    rig.run_until(rig.now + 300_000);
    rig.ok(Command::EmergencyStop);
    assert!(matches!(
        result(&mut rig, 6),
        MoveResult::Finished {
            outcome: MoveOutcome::EmergencyStopped,
            ..
        }
    ));
    // A refused move never started.
    rig.send_id(RequestId(7), move_to(&[(0, 10)]));
    assert_eq!(result(&mut rig, 7), MoveResult::Unknown);
    // Anyone may ask, as anyone may read the status.
    let mut stranger = super::dispatch::network(&mut rig);
    let reply = rig.send_on(
        &mut stranger,
        RequestId(50),
        Command::MoveResult {
            request: RequestId(2),
        },
    );
    assert!(matches!(
        reply,
        Reply::MoveResult(MoveResult::Finished { .. })
    ));
}
