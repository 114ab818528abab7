//! Saving that is really saved: writes that fail or read back wrong are reported in the
//! reply and in `Status`, and a board that writes flash later answers only once it has.

use optalign_protocol::{
    AxisConfig, Capabilities, Command, ErrorCode, PROTOCOL_VERSION, PeerMessage, Reply, Request,
    RequestId, StorageFailure, StorageHealth,
};

use super::rig::{CAPABILITIES, Rig, board};
use crate::config::default_config;
use crate::mark::MARK_LEN;
use crate::sim::{MountModel, SimRng};
use crate::{Controller, LinkKind, RamStorage, Session, Storage, StorageError};

fn fast() -> AxisConfig {
    AxisConfig {
        max_speed: 2_000,
        ..default_config(Capabilities(CAPABILITIES))
    }
}

fn reboot(rig: &Rig) -> Rig {
    Rig::boot(
        rig.controller.storage().power_cycled(),
        [MountModel::new(0)],
        1,
    )
}

fn config_after_reboot(rig: &Rig) -> AxisConfig {
    *reboot(rig).controller.axis_config(0).unwrap()
}

#[test]
fn a_save_that_reads_back_wrong_is_refused_and_shown_in_status() {
    let mut rig = Rig::new(1, 0, default_config(Capabilities(CAPABILITIES)));
    rig.ok(Command::SaveConfig);
    assert_eq!(rig.status().storage, StorageHealth::default());

    rig.ok(Command::SetConfig {
        axis: 0,
        config: fast(),
    });
    rig.controller.storage_mut().set_corrupting(true);
    let reason = rig.error(Command::SaveConfig, ErrorCode::STORAGE);
    assert!(
        reason.contains("not saved") && reason.contains("reading it back"),
        "{reason}"
    );
    let health = rig.status().storage;
    assert_eq!(
        health,
        StorageHealth {
            unsaved: true,
            failed_writes: 1,
            last_failure: Some(StorageFailure::ReadBack),
        }
    );
    // What is stored is the configuration saved before, not the one that failed.
    assert_eq!(
        config_after_reboot(&rig).max_speed,
        default_config(Capabilities(CAPABILITIES)).max_speed
    );

    rig.controller.storage_mut().set_corrupting(false);
    rig.ok(Command::SaveConfig);
    let health = rig.status().storage;
    assert!(!health.unsaved, "{health:?}");
    assert_eq!(health.failed_writes, 1, "failures stay counted");
    assert_eq!(config_after_reboot(&rig), fast());
}

#[test]
fn a_key_that_cannot_be_written_is_refused_with_the_reason() {
    let mut rig = Rig::new(1, 0, default_config(Capabilities(CAPABILITIES)));
    rig.controller.storage_mut().set_failing(true);
    let reason = rig.error(Command::SetKey { key: [9; 32] }, ErrorCode::STORAGE);
    assert!(
        reason.contains("access key") && reason.contains("device failed"),
        "{reason}"
    );
    let health = rig.status().storage;
    assert!(health.unsaved);
    assert_eq!(health.last_failure, Some(StorageFailure::Write));
    assert!(
        !reboot(&rig).status().session.key_provisioned,
        "the key is not stored"
    );
}

#[test]
fn saving_while_axes_move_is_refused_and_changes_nothing() {
    let mut rig = Rig::new(1, 0, default_config(Capabilities(CAPABILITIES)));
    rig.ok(Command::SaveConfig);
    rig.move_to(&[(0, 2_000)]);
    rig.run_until(rig.now + 50_000);
    for command in [Command::SaveConfig, Command::SetKey { key: [3; 32] }] {
        let reason = rig.error(command, ErrorCode::BUSY);
        assert!(reason.contains("idle"), "{reason}");
    }
    assert!(!rig.status().session.key_provisioned);
    rig.settle();
    rig.ok(Command::SetKey { key: [3; 32] });
    assert!(reboot(&rig).status().session.key_provisioned);
}

/// Slots kept in RAM and made durable only by `commit`, like the board's flash: the
/// "device" is `durable`, and committing can be made to fail.
#[derive(Clone)]
struct Deferred {
    ram: RamStorage,
    durable: RamStorage,
    dirty: bool,
    fail_commit: bool,
    commits: u32,
}

impl Storage for Deferred {
    const SLOT_SIZE: usize = RamStorage::SLOT_SIZE;
    const SLOTS: u8 = RamStorage::SLOTS;
    const SLOTS_PER_SECTOR: u8 = RamStorage::SLOTS_PER_SECTOR;

    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError> {
        self.ram.read(slot, buf)
    }

    fn erase(&mut self, slot: u8) -> Result<(), StorageError> {
        self.dirty = true;
        self.ram.erase(slot)
    }

    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError> {
        self.dirty = true;
        self.ram.write(slot, data)
    }

    fn read_mark(&mut self) -> Result<[u8; MARK_LEN], StorageError> {
        self.ram.read_mark()
    }

    fn write_mark(&mut self, mark: &[u8; MARK_LEN]) -> Result<(), StorageError> {
        self.ram.write_mark(mark)
    }

    fn commit(&mut self) -> Result<(), StorageError> {
        self.commits += 1;
        if self.fail_commit {
            return Err(StorageError::ReadBack);
        }
        self.durable = self.ram.clone();
        self.dirty = false;
        Ok(())
    }

    fn unsaved(&self) -> bool {
        self.dirty
    }
}

fn send(
    controller: &mut Controller<Deferred>,
    session: &mut Session,
    id: u32,
    command: Command,
) -> Reply {
    let mut reply = None;
    let request = Request {
        id: RequestId(id),
        command,
    };
    controller.handle(session, &request, 1_000, &mut SimRng::new(1), &mut |m| {
        reply = Some(m)
    });
    match reply {
        Some(PeerMessage::Reply { reply, .. }) => reply,
        other => panic!("expected a reply, got {other:?}"),
    }
}

#[test]
fn a_deferred_write_is_answered_only_once_committed() {
    let storage = Deferred {
        ram: RamStorage::new(),
        durable: RamStorage::new(),
        dirty: false,
        fail_commit: true,
        commits: 0,
    };
    let mut controller = Controller::new(board(1), storage, 1_000, &mut SimRng::new(7));
    let mut session = Session::new(LinkKind::Serial);
    let hello = Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    };
    assert!(matches!(
        send(&mut controller, &mut session, 1, hello),
        Reply::Hello(_)
    ));

    let reply = send(
        &mut controller,
        &mut session,
        2,
        Command::SetKey { key: [5; 32] },
    );
    let Reply::Error(error) = reply else {
        panic!("a failed commit must not be answered Ok: {reply:?}");
    };
    assert_eq!(error.code, ErrorCode::STORAGE);
    assert_eq!(controller.storage().commits, 1);
    let health = controller.status(&session, 1_000).storage;
    assert!(health.unsaved, "the key is still only in RAM: {health:?}");
    assert_eq!(health.last_failure, Some(StorageFailure::ReadBack));
    assert_eq!(
        controller.storage().durable,
        RamStorage::new(),
        "nothing durable"
    );

    controller.storage_mut().fail_commit = false;
    let reply = send(
        &mut controller,
        &mut session,
        3,
        Command::SetKey { key: [5; 32] },
    );
    assert_eq!(reply, Reply::Ok);
    assert!(!controller.status(&session, 1_000).storage.unsaved);
    let rebooted = Controller::new(
        board(1),
        controller.storage().durable.power_cycled(),
        2_000,
        &mut SimRng::new(8),
    );
    assert!(
        rebooted
            .status(&Session::new(LinkKind::Serial), 2_000)
            .session
            .key_provisioned,
        "answered Ok means stored"
    );
}
