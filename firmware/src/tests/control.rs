//! The single-controller rule: one network client controls, others read and may stop.

use optalign_protocol::{Command, ErrorCode, MoveOutcome, Reply, RequestId};

use super::dispatch::{KEY, a_move, authenticate, code, network, plain, reason};
use super::rig::{Rig, values};
use crate::{LinkKind, Session};

/// A rig with a key and two authenticated network sessions.
fn two_clients() -> (Rig, Session, Session) {
    let mut rig = Rig::new(2, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut first = network(&mut rig);
    assert_eq!(authenticate(&mut rig, &mut first, &KEY), Reply::Ok);
    let mut second = network(&mut rig);
    assert_eq!(authenticate(&mut rig, &mut second, &KEY), Reply::Ok);
    (rig, first, second)
}

fn started(reply: &Reply) -> bool {
    matches!(reply, Reply::MoveStarted { .. })
}

#[test]
fn the_first_control_command_claims_and_others_get_busy() {
    let (mut rig, mut first, mut second) = two_clients();
    assert!(started(&rig.send_on(&mut first, RequestId(10), a_move())));
    for (id, command) in [
        (20, a_move()),
        (21, Command::Stop),
        (22, Command::SaveConfig),
        (
            23,
            Command::SetConfig {
                axis: 1,
                config: plain(),
            },
        ),
    ] {
        let reply = rig.send_on(&mut second, RequestId(id), command);
        assert_eq!(code(&reply), Some(ErrorCode::BUSY), "{reply:?}");
        assert!(
            reason(&reply).contains("another client controls"),
            "{reply:?}"
        );
    }
    // The holder keeps control; a failing control command does not lose it.
    let beyond = Command::MoveTo {
        targets: values(&[(0, 1 << 30)]),
    };
    let reply = rig.send_on(&mut first, RequestId(11), beyond);
    assert_eq!(code(&reply), Some(ErrorCode::OUT_OF_LIMITS));
    assert_eq!(
        rig.send_on(&mut first, RequestId(12), Command::Stop),
        Reply::Ok
    );
}

#[test]
fn status_config_and_emergency_stop_stay_open() {
    let (mut rig, mut first, mut second) = two_clients();
    let long = Command::MoveTo {
        targets: values(&[(0, 50_000)]),
    };
    let request = RequestId(10);
    assert!(started(&rig.send_on(&mut first, request, long)));
    rig.run_until(rig.now + 200_000);
    assert!(matches!(
        rig.send_on(&mut second, RequestId(20), Command::Status),
        Reply::Status(_)
    ));
    assert!(matches!(
        rig.send_on(&mut second, RequestId(21), Command::GetConfig { axis: 0 }),
        Reply::Config(_)
    ));
    // An unauthenticated session may stop everything too.
    let mut stranger = network(&mut rig);
    assert_eq!(
        rig.send_on(&mut stranger, RequestId(22), Command::EmergencyStop),
        Reply::Ok
    );
    rig.settle();
    assert_eq!(
        rig.finished().last().map(|f| (f.0, f.1)),
        Some((request, MoveOutcome::EmergencyStopped))
    );
    assert!(!rig.status().axes[0].powered);
}

#[test]
fn serial_is_never_blocked_and_never_claims() {
    let (mut rig, mut first, mut second) = two_clients();
    let mut serial = Session::new(LinkKind::Serial);
    let hello = Command::Hello {
        protocol_version: optalign_protocol::PROTOCOL_VERSION,
    };
    assert!(matches!(
        rig.send_on(&mut serial, RequestId(1), hello),
        Reply::Hello(_)
    ));
    // Serial control while nobody holds the claim does not take it.
    assert!(started(&rig.send_on(&mut serial, RequestId(2), a_move())));
    assert!(started(&rig.send_on(&mut first, RequestId(10), a_move())));
    // Held by the first network client: serial still controls.
    assert_eq!(
        rig.send_on(&mut serial, RequestId(3), Command::Stop),
        Reply::Ok
    );
    assert_eq!(
        code(&rig.send_on(&mut second, RequestId(20), Command::Stop)),
        Some(ErrorCode::BUSY)
    );
}

#[test]
fn ending_the_session_releases_control() {
    let (mut rig, mut first, mut second) = two_clients();
    assert!(started(&rig.send_on(&mut first, RequestId(10), a_move())));
    let busy = rig.send_on(&mut second, RequestId(20), a_move());
    assert_eq!(code(&busy), Some(ErrorCode::BUSY));
    rig.controller.end_session(&mut first);
    assert!(!first.is_handshaken(), "an ended session starts afresh");
    // The refused request was not remembered: the same id now runs.
    assert!(started(&rig.send_on(&mut second, RequestId(20), a_move())));
    // The first client reconnects: now it is the one refused.
    let mut again = network(&mut rig);
    assert_eq!(authenticate(&mut rig, &mut again, &KEY), Reply::Ok);
    assert_eq!(
        code(&rig.send_on(&mut again, RequestId(11), Command::Stop)),
        Some(ErrorCode::BUSY)
    );
    // Ending a session that never held control changes nothing.
    rig.controller.end_session(&mut again);
    assert_eq!(
        code(&rig.send_on(&mut first, RequestId(12), Command::Stop)),
        Some(ErrorCode::HANDSHAKE_REQUIRED)
    );
    let mut third = network(&mut rig);
    authenticate(&mut rig, &mut third, &KEY);
    assert_eq!(
        code(&rig.send_on(&mut third, RequestId(30), Command::Stop)),
        Some(ErrorCode::BUSY)
    );
}

#[test]
fn a_retransmission_is_answered_while_the_old_connection_holds_control() {
    let (mut rig, mut first, mut second) = two_clients();
    let id = RequestId(0xBEEF);
    let first_reply = rig.send_on(&mut first, id, a_move());
    assert!(started(&first_reply));
    // The client reconnected (as `second`) before `first`'s connection was noticed gone.
    assert_eq!(rig.send_on(&mut second, id, a_move()), first_reply);
    rig.settle();
    assert_eq!(rig.finished().len(), 1, "the move ran once");
}

#[test]
fn a_new_key_frees_a_stale_claim() {
    let (mut rig, mut first, _) = two_clients();
    assert!(started(&rig.send_on(&mut first, RequestId(10), a_move())));
    // Keys are written only while the axes are idle: stop them over serial first.
    rig.ok(Command::Stop);
    rig.settle();
    rig.ok(Command::SetKey { key: [9; 32] });
    let mut other = network(&mut rig);
    assert_eq!(authenticate(&mut rig, &mut other, &[9; 32]), Reply::Ok);
    assert_eq!(
        rig.send_on(&mut other, RequestId(20), Command::Stop),
        Reply::Ok
    );
    assert_eq!(
        code(&rig.send_on(&mut first, RequestId(11), Command::Stop)),
        Some(ErrorCode::UNAUTHORIZED)
    );
}

#[test]
fn a_flood_of_stops_never_evicts_the_controllers_replies() {
    let (mut rig, mut first, mut second) = two_clients();
    let id = RequestId(0xF00D);
    let command = Command::MoveBy {
        deltas: values(&[(0, 300)]),
    };
    let reply = rig.send_on(&mut first, id, command.clone());
    assert!(started(&reply));
    rig.settle();
    // Far more stops than the reply memory holds, from everyone.
    let mut stranger = network(&mut rig);
    for n in 0..4 * crate::replay::CAPACITY as u32 {
        let stop = rig.send_on(&mut stranger, RequestId(1000 + n), Command::EmergencyStop);
        assert_eq!(stop, Reply::Ok);
        let busy = rig.send_on(&mut second, RequestId(2000 + n), Command::Stop);
        assert_eq!(code(&busy), Some(ErrorCode::BUSY));
        assert_eq!(
            rig.send_on(&mut first, RequestId(3000 + n), Command::Stop),
            Reply::Ok
        );
    }
    assert_eq!(
        rig.send_on(&mut first, RequestId(4000), Command::ClearEmergency),
        Reply::Ok
    );
    // The controlling client's retransmission is still answered, not run again.
    assert_eq!(rig.send_on(&mut first, id, command), reply);
    rig.settle();
    assert_eq!(rig.position(0), 300);
    assert_eq!(rig.finished().len(), 1);
}

#[test]
fn a_repeated_emergency_stop_runs_every_time() {
    let (mut rig, mut first, _) = two_clients();
    let mut stranger = network(&mut rig);
    let stop = RequestId(50);
    assert_eq!(
        rig.send_on(&mut stranger, stop, Command::EmergencyStop),
        Reply::Ok
    );
    assert_eq!(
        rig.send_on(&mut first, RequestId(10), Command::ClearEmergency),
        Reply::Ok
    );
    let long = Command::MoveTo {
        targets: values(&[(0, 50_000)]),
    };
    assert!(started(&rig.send_on(&mut first, RequestId(11), long)));
    rig.run_until(rig.now + 200_000);
    // The same id again: not a cached answer, a second emergency stop.
    assert_eq!(
        rig.send_on(&mut stranger, stop, Command::EmergencyStop),
        Reply::Ok
    );
    rig.settle();
    assert_eq!(
        rig.finished().last().map(|f| (f.0, f.1)),
        Some((RequestId(11), MoveOutcome::EmergencyStopped))
    );
    assert!(rig.status().emergency_stopped);
}

#[test]
fn only_the_controlling_client_or_serial_clears_the_latch() {
    let (mut rig, mut first, mut second) = two_clients();
    assert!(started(&rig.send_on(&mut first, RequestId(10), a_move())));
    let mut stranger = network(&mut rig);
    assert_eq!(
        rig.send_on(&mut stranger, RequestId(20), Command::EmergencyStop),
        Reply::Ok
    );
    let reply = rig.send_on(&mut stranger, RequestId(21), Command::ClearEmergency);
    assert_eq!(code(&reply), Some(ErrorCode::UNAUTHORIZED));
    let reply = rig.send_on(&mut second, RequestId(22), Command::ClearEmergency);
    assert_eq!(code(&reply), Some(ErrorCode::BUSY));
    // The controller is refused a move until it clears the latch itself.
    let reply = rig.send_on(&mut first, RequestId(11), a_move());
    assert_eq!(code(&reply), Some(ErrorCode::EMERGENCY_STOPPED));
    assert!(rig.status().emergency_stopped);
    let clear = RequestId(12);
    assert_eq!(
        rig.send_on(&mut first, clear, Command::ClearEmergency),
        Reply::Ok
    );
    assert!(!rig.status().emergency_stopped);
    // A retransmitted clear is answered from memory and does not release a newer latch.
    assert_eq!(
        rig.send_on(&mut stranger, RequestId(23), Command::EmergencyStop),
        Reply::Ok
    );
    assert_eq!(
        rig.send_on(&mut first, clear, Command::ClearEmergency),
        Reply::Ok
    );
    assert!(rig.status().emergency_stopped);
    // The serial link (physical access) may always clear it.
    rig.ok(Command::ClearEmergency);
    assert!(!rig.status().emergency_stopped);
    assert!(started(&rig.send_on(&mut first, RequestId(13), a_move())));
}
