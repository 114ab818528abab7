//! Power cuts of the simulated controller in process, against its bench (mounts and flash
//! kept apart from the controller): the shafts stay where the last step left them, the
//! flash holds what was last written, torn when the power went in a write, and a flash
//! file that cannot be written is answered as a storage error, not `Ok`.

use std::sync::Arc;
use std::time::Duration;

use optalign::peer::{Bench, PeerCore, PeerOptions, SimPeer, TimeMode};
use optalign_firmware::Session;
use optalign_protocol::{
    AxisConfig, AxisValue, BootRecord, Command, ErrorCode, Faults, PeerMessage, Reply, Request,
    RequestId, Status,
};

fn options(time: TimeMode) -> PeerOptions {
    PeerOptions {
        axes: 2,
        time,
        ..PeerOptions::default()
    }
}

fn ask(core: &mut PeerCore, session: &mut Session, command: Command) -> Reply {
    let request = Request {
        id: RequestId(rand::random()),
        command,
    };
    let answers = core.handle(session, &request);
    match answers.as_slice() {
        [PeerMessage::Reply { reply, .. }] => reply.clone(),
        other => panic!("{request:?} was answered {other:?}"),
    }
}

fn status(peer: &SimPeer) -> Status {
    match peer.serial_request(Command::Status).as_slice() {
        [
            PeerMessage::Reply {
                reply: Reply::Status(status),
                ..
            },
        ] => status.clone(),
        other => panic!("Status answered {other:?}"),
    }
}

fn move_axis_0(peer: &SimPeer, steps: i32) {
    let targets = [AxisValue { axis: 0, steps }].into_iter().collect();
    let replies = peer.serial_request(Command::MoveTo { targets });
    assert!(
        matches!(
            replies.as_slice(),
            [PeerMessage::Reply {
                reply: Reply::MoveStarted { .. },
                ..
            }]
        ),
        "{replies:?}"
    );
}

async fn until(what: &str, mut done: impl FnMut() -> bool) {
    for _ in 0..500 {
        if done() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    panic!("timed out waiting until {what}");
}

#[tokio::test]
async fn a_power_cut_mid_move_leaves_the_shaft_where_it_was_and_the_axis_flagged() {
    let options = options(TimeMode::Scaled(1.0));
    let peer = SimPeer::start(&options).unwrap();
    peer.core().bench().lock().unwrap().keep_log();
    move_axis_0(&peer, 20_000);
    until("steps are made", || peer.shaft_positions()[0] > 50).await;
    let bench = peer.kill();
    let cut_at = bench.shaft_positions()[0];
    tokio::time::sleep(Duration::from_millis(50)).await;
    assert_eq!(
        peer.shaft_positions()[0],
        cut_at,
        "a dead controller makes no step"
    );
    assert!(
        (50..20_000).contains(&cut_at),
        "the shaft stopped mid-way: {cut_at}"
    );

    let second = SimPeer::start_on_bench(&options, bench).unwrap();
    assert_eq!(second.shaft_positions(), [cut_at, 0], "the mirrors stayed");
    let status = status(&second);
    assert_eq!(status.boot, BootRecord::InterruptedMove);
    assert!(status.axes[0].faults.has(Faults::POSITION_LOST));
    assert!(!status.axes[1].faults.has(Faults::POSITION_LOST));
    assert!(status.axes.iter().all(|axis| !axis.powered));
    let log = second
        .core()
        .bench()
        .lock()
        .unwrap()
        .log()
        .unwrap()
        .total_starts();
    assert_eq!(log, 1, "the log of executions survives the cut");
}

/// Makes the record's write at the end of a move the one the power goes in, at `bytes`.
async fn cut_in_the_record_write(bytes: usize) -> (Arc<SimPeer>, Bench) {
    let options = options(TimeMode::Instant);
    let peer = SimPeer::start(&options).unwrap();
    move_axis_0(&peer, 300);
    until("the first move ends", || !peer.core().is_moving()).await;
    peer.core()
        .bench()
        .lock()
        .unwrap()
        .cut_power_in_write(0, bytes);
    move_axis_0(&peer, 700);
    until("the power fails", || peer.core().is_off()).await;
    let bench = peer.kill();
    assert_eq!(bench.shaft_positions(), [700, 0], "the steps were made");
    (peer, bench)
}

#[tokio::test]
async fn a_power_cut_in_a_flash_write_leaves_it_torn_and_the_moved_axis_flagged() {
    for bytes in [0, 1, 9, 40, 100] {
        let (_dead, bench) = cut_in_the_record_write(bytes).await;
        let second = SimPeer::start_on_bench(&options(TimeMode::Instant), bench).unwrap();
        let status = status(&second);
        assert!(
            status.axes[0].faults.has(Faults::POSITION_LOST),
            "torn at byte {bytes}: {status:?}"
        );
        // The shaft is at 700; the controller either says so or says it does not know.
        assert_eq!(second.shaft_positions(), [700, 0]);
    }
}

#[tokio::test]
async fn a_dead_controller_answers_nothing() {
    let (dead, _) = cut_in_the_record_write(10).await;
    let answers = dead.serial_request(Command::Status);
    assert!(answers.is_empty(), "{answers:?}");
}

#[tokio::test]
async fn a_flash_file_that_cannot_be_written_is_a_storage_error_not_ok() {
    let dir = tempfile::tempdir().unwrap();
    let folder = dir.path().join("state");
    std::fs::create_dir(&folder).unwrap();
    let options = PeerOptions {
        state_file: Some(folder.join("peer.flash")),
        ..options(TimeMode::Instant)
    };
    let mut core = PeerCore::new(&options).unwrap();
    let mut session = core.serial_session();
    let config = match ask(&mut core, &mut session, Command::GetConfig { axis: 0 }) {
        Reply::Config(config) => config,
        other => panic!("{other:?}"),
    };
    let faster = AxisConfig {
        max_speed: config.max_speed + 100,
        ..config
    };
    let set = Command::SetConfig {
        axis: 0,
        config: faster,
    };
    assert_eq!(ask(&mut core, &mut session, set), Reply::Ok);
    assert_eq!(ask(&mut core, &mut session, Command::SaveConfig), Reply::Ok);

    // The folder becomes a file: nothing can be written in it any more.
    std::fs::remove_dir_all(&folder).unwrap();
    std::fs::write(&folder, b"").unwrap();
    let slower = Command::SetConfig { axis: 0, config };
    assert_eq!(ask(&mut core, &mut session, slower), Reply::Ok);
    match ask(&mut core, &mut session, Command::SaveConfig) {
        Reply::Error(error) => {
            assert_eq!(error.code, ErrorCode::STORAGE, "{error}");
            assert!(error.reason.contains("not saved"), "{error}");
        }
        other => panic!("a failed write was answered {other:?}"),
    }
    let Reply::Status(status) = ask(&mut core, &mut session, Command::Status) else {
        panic!("no status");
    };
    assert!(status.storage.unsaved, "{:?}", status.storage);
    assert!(status.storage.failed_writes > 0, "{:?}", status.storage);
}
