//! The dispatcher: handshake, access control, authentication, the request-id memory,
//! validation and configuration.

use optalign_protocol::auth::challenge_tag;
use optalign_protocol::{
    AxisConfig, BacklashMode, Capabilities, Command, ErrorCode, FrameError, MoveOutcome,
    PROTOCOL_VERSION, PeerMessage, REFUSED_SINCE, RefusalDetail, Reply, RequestId, SoftLimits,
};

use super::rig::{CAPABILITIES, Rig, values};
use crate::config::default_config;
use crate::{LinkKind, Session};

pub(super) fn plain() -> AxisConfig {
    AxisConfig {
        backlash_mode: BacklashMode::Off,
        ..default_config(Capabilities(CAPABILITIES))
    }
}

pub(super) fn code(reply: &Reply) -> Option<ErrorCode> {
    reply.error().map(|error| error.code)
}

pub(super) fn reason(reply: &Reply) -> String {
    match reply.error() {
        Some(error) => error.reason.to_string(),
        None => panic!("expected an error, got {reply:?}"),
    }
}

/// The detail of a [`Reply::Refused`].
pub(super) fn detail(reply: &Reply) -> Option<RefusalDetail> {
    match reply {
        Reply::Refused { detail, .. } => Some(*detail),
        _ => None,
    }
}

pub(super) const KEY: [u8; 32] = [7; 32];

/// A network session that completed the handshake.
pub(super) fn network(rig: &mut Rig) -> Session {
    let mut session = Session::new(LinkKind::Network);
    let hello = Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    };
    assert!(matches!(
        rig.send_on(&mut session, RequestId(1), hello),
        Reply::Hello(_)
    ));
    session
}

pub(super) fn authenticate(rig: &mut Rig, session: &mut Session, key: &[u8; 32]) -> Reply {
    let Reply::Challenge { nonce } = rig.send_on(session, RequestId(2), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    let tag = challenge_tag(key, &nonce, &CLIENT_NONCE);
    rig.send_on(
        session,
        RequestId(3),
        Command::AuthResponse {
            tag,
            client_nonce: CLIENT_NONCE,
        },
    )
}

/// The nonce the tests' clients draw.
pub(super) const CLIENT_NONCE: [u8; 16] = [0x33; 16];

/// The response to `nonce` under `key`.
pub(super) fn response(key: &[u8; 32], nonce: &[u8; 16]) -> Command {
    Command::AuthResponse {
        tag: challenge_tag(key, nonce, &CLIENT_NONCE),
        client_nonce: CLIENT_NONCE,
    }
}

pub(super) fn a_move() -> Command {
    Command::MoveTo {
        targets: values(&[(0, 10)]),
    }
}

#[test]
fn hello_first_and_versions_must_match() {
    let mut rig = Rig::new(1, 0, plain());
    let mut session = Session::new(LinkKind::Serial);
    let reply = rig.send_on(&mut session, RequestId(1), Command::Status);
    assert_eq!(code(&reply), Some(ErrorCode::HANDSHAKE_REQUIRED));
    let wrong = PROTOCOL_VERSION + 1;
    let reply = rig.send_on(
        &mut session,
        RequestId(2),
        Command::Hello {
            protocol_version: wrong,
        },
    );
    assert_eq!(code(&reply), Some(ErrorCode::VERSION_MISMATCH));
    assert_eq!(
        reason(&reply),
        format!("peer speaks protocol {PROTOCOL_VERSION}, client sent {wrong}")
    );
    // The controller's version as a field, for a client that knows `Refused`...
    assert_eq!(
        detail(&reply),
        Some(RefusalDetail::ProtocolVersion(PROTOCOL_VERSION))
    );
    // ... and the plain error, which every version decodes, for an older one.
    let reply = rig.send_on(
        &mut session,
        RequestId(20),
        Command::Hello {
            protocol_version: REFUSED_SINCE - 1,
        },
    );
    assert!(
        matches!(&reply, Reply::Error(error) if error.code == ErrorCode::VERSION_MISMATCH),
        "{reply:?}"
    );
    assert!(!session.is_handshaken());
    let hello = Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    };
    let Reply::Hello(identity) = rig.send_on(&mut session, RequestId(3), hello) else {
        panic!("no identity");
    };
    assert_eq!(identity.protocol_version, PROTOCOL_VERSION);
    assert_eq!(
        (identity.board.as_str(), identity.firmware_version.as_str()),
        ("test-bench", "0.1.0")
    );
    assert_eq!((identity.axes, identity.capabilities.0), (1, CAPABILITIES));
}

#[test]
fn network_control_needs_a_key_then_authentication() {
    let mut rig = Rig::new(1, 0, plain());
    let mut net = network(&mut rig);
    // Open commands need nothing.
    assert!(matches!(
        rig.send_on(&mut net, RequestId(10), Command::Status),
        Reply::Status(_)
    ));
    assert!(matches!(
        rig.send_on(&mut net, RequestId(11), Command::GetConfig { axis: 0 }),
        Reply::Config(_)
    ));
    // No key yet: motion is refused with instructions.
    let reply = rig.send_on(&mut net, RequestId(12), a_move());
    assert_eq!(code(&reply), Some(ErrorCode::NO_KEY));
    assert!(
        reason(&reply).contains("optalign provision --serial PATH --key"),
        "{reply:?}"
    );
    assert_eq!(
        code(&rig.send_on(&mut net, RequestId(13), Command::AuthChallenge)),
        Some(ErrorCode::NO_KEY)
    );
    // Keys and Wi-Fi only over serial.
    let reply = rig.send_on(&mut net, RequestId(14), Command::SetKey { key: KEY });
    assert_eq!(code(&reply), Some(ErrorCode::SERIAL_ONLY));
    let wifi = Command::ProvisionWifi {
        ssid: "lab".try_into().unwrap(),
        passphrase: "pw".try_into().unwrap(),
    };
    assert_eq!(
        code(&rig.send_on(&mut net, RequestId(15), wifi.clone())),
        Some(ErrorCode::SERIAL_ONLY)
    );
    rig.ok(wifi);
    rig.ok(Command::SetKey { key: KEY });
    assert_eq!(rig.controller.wifi().map(|w| w.ssid.as_str()), Some("lab"));
    // Key set, session not authenticated.
    assert_eq!(
        code(&rig.send_on(&mut net, RequestId(16), a_move())),
        Some(ErrorCode::UNAUTHORIZED)
    );
    // A wrong key fails and leaves the session unauthenticated.
    assert_eq!(
        code(&authenticate(&mut rig, &mut net, &[8; 32])),
        Some(ErrorCode::AUTH_FAILED)
    );
    assert_eq!(
        code(&rig.send_on(&mut net, RequestId(17), a_move())),
        Some(ErrorCode::UNAUTHORIZED)
    );
    // The right key works, once the backoff after the failure has run out.
    rig.now += crate::backoff::FIRST_DELAY_US;
    assert_eq!(authenticate(&mut rig, &mut net, &KEY), Reply::Ok);
    let status = rig.controller.status(&net, rig.now).session;
    assert!(status.authenticated && status.key_provisioned && !status.trusted_link);
    assert!(matches!(
        rig.send_on(&mut net, RequestId(18), a_move()),
        Reply::MoveStarted { .. }
    ));
    // A new key (written while the axes are idle) revokes the session.
    rig.settle();
    rig.ok(Command::SetKey { key: [9; 32] });
    assert_eq!(
        code(&rig.send_on(&mut net, RequestId(19), Command::Stop)),
        Some(ErrorCode::UNAUTHORIZED)
    );
    // The serial link needs nothing.
    assert!(rig.status().session.trusted_link);
}

#[test]
fn a_nonce_answers_one_response() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut net = network(&mut rig);
    let Reply::Challenge { nonce } = rig.send_on(&mut net, RequestId(2), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    let answer = response(&KEY, &nonce);
    assert_eq!(
        rig.send_on(&mut net, RequestId(3), answer.clone()),
        Reply::Ok
    );
    // Replaying the same tag (on another connection too) fails: the nonce is gone.
    let reply = rig.send_on(&mut net, RequestId(4), answer.clone());
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_FAILED));
    let mut other = network(&mut rig);
    let reply = rig.send_on(&mut other, RequestId(3), answer);
    assert_eq!(code(&reply), Some(ErrorCode::AUTH_FAILED));
    // Challenges differ.
    let Reply::Challenge { nonce: second } =
        rig.send_on(&mut other, RequestId(5), Command::AuthChallenge)
    else {
        panic!("no challenge");
    };
    assert_ne!(nonce, second);
}

#[test]
fn a_repeated_challenge_request_gets_the_same_nonce() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let mut net = network(&mut rig);
    let challenge = |rig: &mut Rig, net: &mut Session, id| match rig.send_on(
        net,
        RequestId(id),
        Command::AuthChallenge,
    ) {
        Reply::Challenge { nonce } => nonce,
        other => panic!("no challenge: {other:?}"),
    };
    // A duplicated or retransmitted AuthChallenge: the client answers the first reply.
    let first = challenge(&mut rig, &mut net, 2);
    assert_eq!(challenge(&mut rig, &mut net, 2), first);
    // Another request is another challenge.
    let fresh = challenge(&mut rig, &mut net, 3);
    assert_ne!(fresh, first);
    assert_eq!(
        rig.send_on(&mut net, RequestId(4), response(&KEY, &fresh)),
        Reply::Ok
    );
    // Once answered, even the same request id draws a new nonce.
    assert_ne!(challenge(&mut rig, &mut net, 3), fresh);
}

#[test]
fn a_retransmitted_move_runs_once_even_across_sessions() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    let id = RequestId(0xDEAD);
    let command = Command::MoveBy {
        deltas: values(&[(0, 500)]),
    };
    let first = rig.send_id(id, command.clone());
    assert!(matches!(first, Reply::MoveStarted { .. }));
    rig.settle();
    let motor_steps = rig.status().axes[0].motor_steps;
    // Same session, then a reconnected authenticated network session.
    assert_eq!(rig.send_id(id, command.clone()), first);
    let mut net = network(&mut rig);
    authenticate(&mut rig, &mut net, &KEY);
    assert_eq!(rig.send_on(&mut net, id, command.clone()), first);
    rig.settle();
    assert_eq!(rig.status().axes[0].motor_steps, motor_steps);
    assert_eq!(rig.position(0), 500);
    assert_eq!(rig.finished().len(), 1);
    // A session without access gets the access error, not the cached reply.
    let mut stranger = network(&mut rig);
    assert_eq!(
        code(&rig.send_on(&mut stranger, id, command)),
        Some(ErrorCode::UNAUTHORIZED)
    );
    // The same id with another command is a new request.
    let other = rig.send_id(
        id,
        Command::MoveBy {
            deltas: values(&[(0, 1)]),
        },
    );
    assert!(matches!(other, Reply::MoveStarted { .. }));
    rig.settle();
    assert_eq!(rig.position(0), 501);
    // Errors are remembered too: a retried bad move gets the same answer.
    let bad = Command::MoveTo {
        targets: values(&[(0, 1 << 30)]),
    };
    let first = rig.send_id(RequestId(1), bad.clone());
    assert_eq!(rig.send_id(RequestId(1), bad), first);
}

#[test]
fn soft_limits_reject_without_clamping() {
    let config = AxisConfig {
        limits: SoftLimits {
            min: -500,
            max: 800,
        },
        ..plain()
    };
    let mut rig = Rig::new(2, 0, config);
    let reply = rig.move_to(&[(0, 100), (1, 801)]);
    assert_eq!(code(&reply), Some(ErrorCode::OUT_OF_LIMITS));
    assert_eq!(
        reason(&reply),
        "axis 1: target 801 outside soft limits -500..=800"
    );
    rig.settle();
    assert!(rig.driver.steps.is_empty(), "a rejected move moves no axis");
    assert!(rig.finished().is_empty());
    let reason = rig.error(
        Command::MoveBy {
            deltas: values(&[(0, -501)]),
        },
        ErrorCode::OUT_OF_LIMITS,
    );
    assert!(reason.contains("target -501"), "{reason}");
    rig.error(
        Command::MoveBy {
            deltas: values(&[(0, i32::MIN)]),
        },
        ErrorCode::OUT_OF_LIMITS,
    );
    rig.error(
        Command::SetPosition {
            axis: 0,
            position: 900,
        },
        ErrorCode::OUT_OF_LIMITS,
    );
    rig.move_and_settle(&[(0, 800), (1, -500)]);
    assert_eq!((rig.position(0), rig.position(1)), (800, -500));
}

#[test]
fn axes_must_exist_and_appear_once() {
    let mut rig = Rig::new(2, 0, plain());
    let reason = rig.error(
        Command::MoveTo {
            targets: values(&[(2, 0)]),
        },
        ErrorCode::UNKNOWN_AXIS,
    );
    assert_eq!(reason, "axis 2 does not exist (this peer has 2 axes)");
    rig.error(
        Command::MoveTo {
            targets: values(&[(1, 0), (1, 5)]),
        },
        ErrorCode::MALFORMED,
    );
    rig.error(Command::GetConfig { axis: 9 }, ErrorCode::UNKNOWN_AXIS);
    rig.error(
        Command::SetConfig {
            axis: 200,
            config: plain(),
        },
        ErrorCode::UNKNOWN_AXIS,
    );
    rig.error(
        Command::SetPosition {
            axis: 2,
            position: 0,
        },
        ErrorCode::UNKNOWN_AXIS,
    );
}

#[test]
fn configuration_round_trips_and_is_validated() {
    let mut rig = Rig::new(1, 0, plain());
    let config = AxisConfig {
        max_speed: 1234,
        backlash: 17,
        ..plain()
    };
    rig.ok(Command::SetConfig { axis: 0, config });
    assert_eq!(
        rig.send(Command::GetConfig { axis: 0 }),
        Reply::Config(config)
    );
    let reason = rig.error(
        Command::SetConfig {
            axis: 0,
            config: AxisConfig {
                max_speed: 0,
                ..config
            },
        },
        ErrorCode::INVALID_CONFIG,
    );
    assert!(reason.contains("max_speed"), "{reason}");
    rig.error(
        Command::SetConfig {
            axis: 0,
            config: AxisConfig {
                backlash: 5000,
                ..config
            },
        },
        ErrorCode::INVALID_CONFIG,
    );
    assert_eq!(
        rig.send(Command::GetConfig { axis: 0 }),
        Reply::Config(config)
    );
}

#[test]
fn link_errors_are_reported_without_an_id() {
    let mut rig = Rig::new(1, 0, plain());
    let mut out = Vec::new();
    rig.controller
        .link_error(FrameError::BadCrc, &mut |m| out.push(m));
    let [PeerMessage::LinkError(error)] = out.as_slice() else {
        panic!("{out:?}");
    };
    assert_eq!(error.code, ErrorCode::BAD_CRC);
    assert!(rig.driver.steps.is_empty());
}

#[test]
fn emergency_stop_is_open_to_any_session() {
    let mut rig = Rig::new(1, 0, plain());
    rig.ok(Command::SetKey { key: KEY });
    rig.send_id(RequestId(1), a_move());
    let mut net = network(&mut rig);
    assert_eq!(
        rig.send_on(&mut net, RequestId(50), Command::EmergencyStop),
        Reply::Ok
    );
    rig.settle();
    assert_eq!(rig.finished()[0].1, MoveOutcome::EmergencyStopped);
}

#[test]
fn every_start_up_has_its_own_boot_nonce() {
    let mut rig = Rig::new(1, 0, plain());
    for id in [1, 2] {
        let mut session = Session::new(LinkKind::Serial);
        let hello = Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        };
        let Reply::Hello(identity) = rig.send_on(&mut session, RequestId(id), hello) else {
            panic!("no identity");
        };
        assert_eq!(identity.boot_nonce, rig.controller.boot_nonce);
    }
    let nonces: Vec<u64> = (0..8)
        .map(|seed| {
            let mut rng = crate::sim::SimRng::new(seed);
            crate::Controller::new(super::rig::board(1), crate::RamStorage::new(), 0, &mut rng)
                .boot_nonce
        })
        .collect();
    for (i, nonce) in nonces.iter().enumerate() {
        assert!(!nonces[i + 1..].contains(nonce), "{nonces:?}");
    }
}
