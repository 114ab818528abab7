//! Positions, configuration and credentials across reboots, resets during moves, torn
//! writes and failing storage.

use optalign_protocol::{
    AxisConfig, BacklashMode, BootRecord, Capabilities, Command, ErrorCode, Faults, Reply, Slack,
};

use super::rig::{CAPABILITIES, Rig, values};
use crate::config::default_config;
use crate::mark;
use crate::sim::MountModel;
use crate::{RamStorage, Storage};

fn one_sided(backlash: u16) -> AxisConfig {
    AxisConfig {
        backlash,
        backlash_mode: BacklashMode::OneSided,
        ..default_config(Capabilities(CAPABILITIES))
    }
}

/// Powers the rig off and on (or resets it, in the middle of whatever it was doing): same
/// storage and mounts, a new controller.
fn reboot(rig: &Rig) -> Rig {
    let axes = rig.status().axes.len() as u8;
    let mounts: Vec<MountModel> = (0..axes)
        .map(|a| rig.driver.sim.mount(a).unwrap().clone())
        .collect();
    Rig::boot(rig.controller.storage().power_cycled(), mounts, axes)
}

#[test]
fn a_fresh_board_starts_at_zero_without_faults() {
    let rig = Rig::boot(RamStorage::new(), [MountModel::new(0)], 1);
    let status = rig.status();
    let axis = status.axes[0];
    assert_eq!(
        (axis.position, axis.motor_steps, axis.slack),
        (0, 0, Slack::Unknown)
    );
    assert!(axis.faults.is_clear() && !axis.powered && !status.emergency_stopped);
    assert!(rig.controller.wifi().is_none() && !status.session.key_provisioned);
    assert_eq!(status.boot, BootRecord::NoRecordYet, "it says so");
}

#[test]
fn state_survives_a_reboot() {
    let mut rig = Rig::new(2, 30, one_sided(30));
    rig.ok(Command::SaveConfig);
    rig.ok(Command::SetKey { key: [3; 32] });
    rig.ok(Command::ProvisionWifi {
        ssid: "optics-lab".try_into().unwrap(),
        passphrase: "hunter22".try_into().unwrap(),
    });
    rig.move_and_settle(&[(0, -700), (1, 1200)]);
    // Configured but not saved: not in the record.
    let unsaved = AxisConfig {
        max_speed: 999,
        ..one_sided(30)
    };
    rig.ok(Command::SetConfig {
        axis: 1,
        config: unsaved,
    });
    rig.move_and_settle(&[(0, -650)]);
    let before = rig.status();

    let mut rig = reboot(&rig);
    let after = rig.status();
    assert_eq!(after.boot, BootRecord::Restored);
    for (a, b) in before.axes.iter().zip(&after.axes) {
        assert_eq!(
            (a.position, a.motor_steps, a.slack),
            (b.position, b.motor_steps, b.slack)
        );
        assert!(b.faults.is_clear());
    }
    assert!(after.session.key_provisioned);
    assert_eq!(
        rig.controller.wifi().map(|w| w.passphrase.as_str()),
        Some("hunter22")
    );
    assert_eq!(
        rig.send(Command::GetConfig { axis: 1 }),
        Reply::Config(one_sided(30))
    );
    // The restored slack state keeps moves exact: a small move in the approach direction
    // needs no overshoot.
    let steps = rig.driver.steps.len();
    rig.move_and_settle(&[(0, -640)]);
    assert_eq!(rig.driver.steps.len() - steps, 10);
    rig.move_and_settle(&[(0, -660), (1, 0)]);
    assert_eq!((rig.shaft(0), rig.shaft(1)), (-660, 0));
}

#[test]
fn the_slack_is_saved_for_the_saved_backlash() {
    let mut rig = Rig::new(1, 30, one_sided(30));
    rig.ok(Command::SaveConfig);
    // Unsaved: a smaller backlash in force while the axis comes to rest pressed positive.
    rig.ok(Command::SetConfig {
        axis: 0,
        config: one_sided(10),
    });
    rig.move_and_settle(&[(0, -50)]);
    let mut rig = reboot(&rig);
    assert_eq!(rig.status().axes[0].slack, Slack::TakenUpPositive);
    // Still pressed positive for the saved backlash of 30: a small positive move is direct.
    let steps = rig.driver.steps.len();
    rig.move_and_settle(&[(0, -45)]);
    assert_eq!(rig.driver.steps.len() - steps, 5);
    assert_eq!(rig.shaft(0), -45);
}

#[test]
fn a_torn_write_falls_back_to_the_previous_record_and_flags_the_axis() {
    let mut rig = Rig::new(2, 0, one_sided(0));
    rig.move_and_settle(&[(0, 100), (1, 50)]);
    rig.move_and_settle(&[(0, 200)]);
    // Power fails while the record of the next move's end is written.
    rig.controller.storage_mut().tear_next_write(20);
    rig.move_and_settle(&[(0, 300)]);
    let rig = reboot(&rig);
    assert_eq!((rig.position(0), rig.position(1)), (200, 50));
    // The record is the previous one, but the move was marked: its position is not trusted.
    let status = rig.status();
    assert!(status.axes[0].faults.has(Faults::POSITION_LOST));
    assert!(status.axes[1].faults.is_clear());
    assert_eq!(status.boot, BootRecord::InterruptedMove);
}

#[test]
fn corrupt_records_flag_lost_positions() {
    let mut rig = Rig::new(2, 0, one_sided(0));
    rig.move_and_settle(&[(0, 100)]);
    rig.move_and_settle(&[(0, 200)]);
    let slot = <RamStorage as Storage>::SLOT_SIZE;
    // The slots holding records, newest first.
    let mut storage = rig.controller.storage().clone();
    let mut held: Vec<(u32, usize)> = (0..usize::from(RamStorage::SLOTS))
        .filter_map(|at| {
            let bytes = &storage.as_bytes()[at * slot..][..slot];
            let (sequence, _) = crate::record::decode(bytes).ok()??;
            Some((sequence, at))
        })
        .collect();
    held.sort_unstable_by(|a, b| b.cmp(a));
    // The newest record is corrupt: the one before it is used.
    storage.as_bytes_mut()[held[0].1 * slot + 30] ^= 0x40;
    let mut rebooted = Rig::boot(storage.clone(), [MountModel::new(0), MountModel::new(0)], 2);
    assert_eq!(rebooted.position(0), 100);
    // All corrupt: defaults and POSITION_LOST on every axis, until declared.
    for &(_, at) in &held[1..] {
        storage.as_bytes_mut()[at * slot + 30] ^= 0x40;
    }
    rebooted = Rig::boot(storage, [MountModel::new(0), MountModel::new(0)], 2);
    let status = rebooted.status();
    assert!(
        status
            .axes
            .iter()
            .all(|a| a.faults.has(Faults::POSITION_LOST) && a.position == 0)
    );
    assert_eq!(status.boot, BootRecord::Unreadable);
    rebooted.ok(Command::SetPosition {
        axis: 0,
        position: 200,
    });
    let status = rebooted.status();
    assert!(status.axes[0].faults.is_clear() && status.axes[1].faults.has(Faults::POSITION_LOST));
    // The declaration was saved; the axis not declared stays lost, though the record now
    // reads.
    let mut again = reboot(&rebooted);
    assert_eq!(again.position(0), 200);
    let status = again.status();
    assert!(status.axes[0].faults.is_clear() && status.axes[1].faults.has(Faults::POSITION_LOST));
    again.error(
        Command::MoveTo {
            targets: values(&[(1, 10)]),
        },
        ErrorCode::AXIS_FAULT,
    );
}

#[test]
fn failing_storage_is_reported_and_never_stops_motion() {
    let mut rig = Rig::new(1, 0, one_sided(0));
    rig.controller.storage_mut().set_failing(true);
    let reason = rig.error(Command::SaveConfig, ErrorCode::STORAGE);
    assert!(reason.contains("not saved"), "{reason}");
    rig.error(Command::SetKey { key: [1; 32] }, ErrorCode::STORAGE);
    // The key is in force even though it was not saved.
    assert!(rig.status().session.key_provisioned);
    rig.move_and_settle(&[(0, 400)]);
    assert_eq!(rig.shaft(0), 400);
    // SaveConfig, SetKey, the motion mark and the record at the end of the move.
    assert_eq!(rig.controller.storage_failures(), 4);
    rig.controller.storage_mut().set_failing(false);
    rig.ok(Command::SaveConfig);
    assert_eq!(reboot(&rig).position(0), 400);
}

#[test]
fn a_record_with_more_axes_than_the_board_is_fine() {
    let mut rig = Rig::new(3, 0, one_sided(0));
    rig.move_and_settle(&[(2, 50), (0, 20)]);
    let storage = rig.controller.storage().clone();
    let fewer = Rig::boot(storage.clone(), [MountModel::new(0)], 1);
    assert_eq!(fewer.position(0), 20);
    // A board with more axes than the record: the extra ones are not restored.
    let more = Rig::boot(storage, (0..4).map(|_| MountModel::new(0)), 4);
    let status = more.status();
    assert_eq!(status.axes[2].position, 50);
    assert!(status.axes[3].faults.has(Faults::POSITION_LOST));
}

#[test]
fn a_reset_during_a_move_flags_the_moving_axes_until_re_zeroed() {
    let mut rig = Rig::new(3, 0, super::dispatch::plain());
    rig.move_and_settle(&[(2, 70)]);
    rig.move_to(&[(0, 2000), (1, -1000)]);
    rig.run_until(rig.now + 400_000);
    let (shaft0, shaft1) = (rig.shaft(0), rig.shaft(1));
    assert!(shaft0 > 0 && shaft0 < 2000, "{shaft0}");
    // Reset mid-move: the record still holds the positions from before it.
    let mut rig = reboot(&rig);
    let status = rig.status();
    assert_eq!(status.boot, BootRecord::InterruptedMove);
    assert!(
        status.axes[..2]
            .iter()
            .all(|a| a.faults.has(Faults::POSITION_LOST))
    );
    assert!(status.axes[2].faults.is_clear() && status.axes[2].position == 70);
    // Lost axes refuse to move, saying how to re-zero; nothing steps.
    let reason = rig.error(
        Command::MoveBy {
            deltas: values(&[(2, 5), (0, 10)]),
        },
        ErrorCode::AXIS_FAULT,
    );
    assert!(
        reason.contains("axis 0") && reason.contains("SetPosition"),
        "{reason}"
    );
    rig.settle();
    assert!(rig.driver.steps.is_empty());
    // Others still move.
    rig.move_and_settle(&[(2, 80)]);
    // Re-zeroing one axis clears it and survives a reset; the other stays lost.
    rig.ok(Command::SetPosition {
        axis: 0,
        position: shaft0,
    });
    let mut rig = reboot(&rig);
    let status = rig.status();
    assert!(status.axes[0].faults.is_clear() && status.axes[1].faults.has(Faults::POSITION_LOST));
    assert_eq!(rig.position(0), shaft0);
    rig.move_and_settle(&[(0, 1500)]);
    assert_eq!(rig.shaft(0), 1500);
    rig.ok(Command::SetPosition {
        axis: 1,
        position: shaft1,
    });
    rig.move_and_settle(&[(1, 0)]);
    assert_eq!(rig.shaft(1), 0);
    assert!(
        reboot(&rig)
            .status()
            .axes
            .iter()
            .all(|a| a.faults.is_clear())
    );
}

#[test]
fn the_mark_is_set_before_the_first_step_and_cleared_with_the_record() {
    let marked = |rig: &mut Rig| {
        let bytes = rig.controller.storage_mut().read_mark().unwrap();
        mark::decode(&bytes)
    };
    let mut rig = Rig::new(3, 0, one_sided(0));
    rig.move_to(&[(1, 500)]);
    assert_eq!(marked(&mut rig), 0, "accepted, not started");
    let first_step = rig.controller.next_deadline_us().unwrap();
    rig.run_until(first_step);
    assert_eq!(marked(&mut rig), 0b010);
    // A move of another axis replacing it adds its axis; the first stays marked until the
    // record holds where it stopped.
    rig.move_to(&[(2, 300)]);
    for _ in 0..1000 {
        if rig.shaft(2) != 0 {
            break;
        }
        rig.run_until(rig.now + 1_000);
    }
    assert_ne!(rig.shaft(2), 0, "the replacing move started");
    assert_eq!(marked(&mut rig), 0b110);
    rig.settle();
    assert_eq!(marked(&mut rig), 0, "the record holds the end positions");
    // A mark the record write did not clear (power lost) flags the axes at start-up.
    rig.controller.storage_mut().tear_next_write(0);
    rig.move_and_settle(&[(0, 10)]);
    let storage = rig.controller.storage().power_cycled();
    let rebooted = Rig::boot(storage, (0..3).map(|_| MountModel::new(0)), 3);
    let lost: Vec<bool> = rebooted
        .status()
        .axes
        .iter()
        .map(|a| a.faults.has(Faults::POSITION_LOST))
        .collect();
    assert_eq!(lost, [true, false, false]);
}

#[test]
fn a_garbled_mark_flags_every_axis() {
    let mut storage = RamStorage::new();
    storage.write_mark(&[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    let rig = Rig::boot(storage, [MountModel::new(0), MountModel::new(0)], 2);
    let status = rig.status();
    assert_eq!(status.boot, BootRecord::InterruptedMove);
    assert!(
        status
            .axes
            .iter()
            .all(|a| a.faults.has(Faults::POSITION_LOST))
    );
}

/// Entropy that repeats itself exactly: every boot, every draw.
struct Stuck;

impl crate::RngSource for Stuck {
    fn fill(&mut self, buf: &mut [u8]) {
        buf.fill(0xA5);
    }
}

#[test]
fn challenges_differ_across_boots_when_the_entropy_repeats() {
    use super::dispatch::{KEY, network};
    use optalign_protocol::{Command, Reply, RequestId};

    let challenge = |rig: &mut Rig| {
        let mut net = network(rig);
        match rig.send_drawing(&mut net, RequestId(2), Command::AuthChallenge, &mut Stuck) {
            Reply::Challenge { nonce } => nonce,
            other => panic!("no challenge: {other:?}"),
        }
    };
    let mut rig = Rig::boot(RamStorage::new(), [MountModel::new(0)], 1);
    rig.ok(Command::SetKey { key: KEY });
    let mut seen = vec![challenge(&mut rig), challenge(&mut rig)];
    for _ in 0..3 {
        // A reset before anything else is written: only the boot counter moved on.
        rig = reboot(&rig);
        seen.push(challenge(&mut rig));
        seen.push(challenge(&mut rig));
    }
    let mut distinct = seen.clone();
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), seen.len(), "a challenge repeated: {seen:?}");
    // Each boot's number is in its nonces: 1, 1, 2, 2, 3, 3, 4, 4.
    let boots: Vec<u32> = seen
        .iter()
        .map(|nonce| u32::from_le_bytes(nonce[..4].try_into().unwrap()))
        .collect();
    assert_eq!(boots, [1, 1, 2, 2, 3, 3, 4, 4]);
}

#[test]
fn no_challenge_is_issued_until_the_boot_counter_is_stored() {
    use super::dispatch::{KEY, code, network};
    use optalign_protocol::{Command, ErrorCode, Reply, RequestId};

    let mut rig = Rig::boot(RamStorage::new(), [MountModel::new(0)], 1);
    rig.ok(Command::SetKey { key: KEY });
    let mut storage = rig.controller.storage().power_cycled();
    storage.set_failing(true);
    let mut rig = Rig::boot(storage, [MountModel::new(0)], 1);
    let mut net = network(&mut rig);
    let reply = rig.send_on(&mut net, RequestId(2), Command::AuthChallenge);
    assert_eq!(code(&reply), Some(ErrorCode::STORAGE), "{reply:?}");
    rig.controller.storage_mut().set_failing(false);
    let reply = rig.send_on(&mut net, RequestId(3), Command::AuthChallenge);
    assert!(matches!(reply, Reply::Challenge { .. }), "{reply:?}");
}

#[test]
fn a_lost_axis_moves_only_relatively_in_recovery_and_stays_lost_until_declared() {
    let mut rig = Rig::new(2, 0, super::dispatch::plain());
    rig.move_to(&[(0, 2000)]);
    rig.run_until(rig.now + 400_000);
    let cut = rig.shaft(0);
    assert!(cut > 0 && cut < 2000, "{cut}");
    let mut rig = reboot(&rig);
    let stale = rig.position(0);
    assert!(rig.status().axes[0].faults.has(Faults::POSITION_LOST));

    // Relative moves in recovery mode move the shaft exactly; the axis stays lost.
    for delta in [300, -450] {
        let reply = rig.send(Command::RecoveryMoveBy {
            deltas: values(&[(0, delta)]),
        });
        assert!(matches!(reply, Reply::MoveStarted { .. }), "{reply:?}");
        rig.settle();
    }
    assert_eq!(rig.shaft(0), cut - 150);
    assert_eq!(
        rig.position(0),
        stale - 150,
        "the counter moves by the deltas"
    );
    assert!(rig.status().axes[0].faults.has(Faults::POSITION_LOST));
    // Absolute and ordinary relative moves are still refused, naming the recovery mode.
    let reason = rig.error(
        Command::MoveBy {
            deltas: values(&[(0, 10)]),
        },
        ErrorCode::AXIS_FAULT,
    );
    assert!(reason.contains("RecoveryMoveBy"), "{reason}");
    rig.error(
        Command::MoveTo {
            targets: values(&[(0, 10)]),
        },
        ErrorCode::AXIS_FAULT,
    );
    // A recovery step wider than the soft limits is refused and nothing steps.
    let limits = rig.status().axes[0].limits;
    let width = limits.max - limits.min;
    let steps_before = rig.driver.steps.len();
    let reason = rig.error(
        Command::RecoveryMoveBy {
            deltas: values(&[(0, width + 1)]),
        },
        ErrorCode::OUT_OF_LIMITS,
    );
    assert!(reason.contains("width"), "{reason}");
    rig.settle();
    assert_eq!(rig.driver.steps.len(), steps_before);
    // On an axis that is not lost it is an ordinary relative move, limits checked.
    let reply = rig.send(Command::RecoveryMoveBy {
        deltas: values(&[(1, 25)]),
    });
    assert!(matches!(reply, Reply::MoveStarted { .. }), "{reply:?}");
    rig.settle();
    assert_eq!(rig.shaft(1), 25);
    rig.error(
        Command::RecoveryMoveBy {
            deltas: values(&[(1, limits.max)]),
        },
        ErrorCode::OUT_OF_LIMITS,
    );

    // Still lost after a reset; declared, it moves as usual.
    let mut rig = reboot(&rig);
    assert!(rig.status().axes[0].faults.has(Faults::POSITION_LOST));
    rig.ok(Command::SetPosition {
        axis: 0,
        position: cut - 150,
    });
    rig.move_and_settle(&[(0, 0)]);
    assert_eq!(rig.shaft(0), 0);
    assert!(rig.status().axes[0].faults.is_clear());
}

#[test]
fn recovery_moves_end_on_the_approach_side_with_one_sided_compensation() {
    let mut rig = Rig::new(1, 30, one_sided(30));
    rig.move_to(&[(0, 2000)]);
    rig.run_until(rig.now + 400_000);
    let mut rig = reboot(&rig);
    assert!(rig.status().axes[0].faults.has(Faults::POSITION_LOST));
    rig.ok(Command::SetConfig {
        axis: 0,
        config: one_sided(30),
    });
    for (i, delta) in [-200, 120, -50, 60].into_iter().enumerate() {
        let before = rig.shaft(0);
        let reply = rig.send(Command::RecoveryMoveBy {
            deltas: values(&[(0, delta)]),
        });
        assert!(matches!(reply, Reply::MoveStarted { .. }), "{reply:?}");
        rig.settle();
        let last = *rig.steps_of(0).last().unwrap();
        assert_eq!(last.direction, crate::StepDirection::Forward, "{delta}");
        // Pressed against the approach contact, the load then moves by exactly the delta
        // (the first move starts with the slack unknown).
        if i > 0 {
            assert_eq!(rig.shaft(0), before + delta, "{delta}");
        }
    }
    assert!(rig.status().axes[0].faults.has(Faults::POSITION_LOST));
}
