//! Positions, configuration and credentials across reboots, torn writes and failing storage.

use optalign_protocol::{
    AxisConfig, BacklashMode, Capabilities, Command, ErrorCode, Faults, Reply, Slack,
};

use super::rig::{CAPABILITIES, Rig};
use crate::config::default_config;
use crate::sim::MountModel;
use crate::{RamStorage, Storage};

fn one_sided(backlash: u16) -> AxisConfig {
    AxisConfig {
        backlash,
        backlash_mode: BacklashMode::OneSided,
        ..default_config(Capabilities(CAPABILITIES))
    }
}

/// Powers the rig off and on: same storage and mounts, a new controller.
fn reboot(rig: &Rig) -> Rig {
    let axes = rig.status().axes.len() as u8;
    let mounts: Vec<MountModel> = (0..axes)
        .map(|a| rig.driver.sim.mount(a).unwrap().clone())
        .collect();
    Rig::boot(rig.controller.storage().clone(), mounts, axes)
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
fn a_torn_write_falls_back_to_the_previous_record() {
    let mut rig = Rig::new(1, 0, one_sided(0));
    rig.move_and_settle(&[(0, 100)]);
    rig.move_and_settle(&[(0, 200)]);
    rig.controller.storage_mut().tear_next_write(20);
    rig.move_and_settle(&[(0, 300)]);
    let rig = reboot(&rig);
    assert_eq!(rig.position(0), 200);
    assert!(rig.status().axes[0].faults.is_clear());
}

#[test]
fn corrupt_records_flag_lost_positions() {
    let mut rig = Rig::new(2, 0, one_sided(0));
    rig.move_and_settle(&[(0, 100)]);
    rig.move_and_settle(&[(0, 200)]);
    let slot = <RamStorage as Storage>::SLOT_SIZE;
    // The newest record is corrupt: the older one is used.
    let mut storage = rig.controller.storage().clone();
    storage.as_bytes_mut()[slot + 30] ^= 0x40;
    let mut rebooted = Rig::boot(storage.clone(), [MountModel::new(0), MountModel::new(0)], 2);
    assert_eq!(rebooted.position(0), 100);
    // Both corrupt: defaults and POSITION_LOST on every axis, until declared.
    storage.as_bytes_mut()[30] ^= 0x40;
    rebooted = Rig::boot(storage, [MountModel::new(0), MountModel::new(0)], 2);
    let status = rebooted.status();
    assert!(
        status
            .axes
            .iter()
            .all(|a| a.faults.has(Faults::POSITION_LOST) && a.position == 0)
    );
    rebooted.ok(Command::SetPosition {
        axis: 0,
        position: 200,
    });
    let status = rebooted.status();
    assert!(status.axes[0].faults.is_clear() && status.axes[1].faults.has(Faults::POSITION_LOST));
    // The declaration was saved.
    let again = reboot(&rebooted);
    assert_eq!(again.position(0), 200);
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
    assert_eq!(rig.controller.storage_failures(), 3);
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
