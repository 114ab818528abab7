//! The hardware-in-the-loop suite: the host link against a controller.
//!
//! By default every case starts its own simulated peer (the real firmware core on
//! simulated mounts) on a loopback port and a pseudo-terminal. With
//! `OPTALIGN_HIL=tcp://HOST:PORT` (and `OPTALIGN_KEY`) or `OPTALIGN_HIL=serial://PATH` the
//! same cases run against that board; cases that need the simulator's hidden truth or a
//! second peer say they are skipped.

#[path = "suite/rezero.rs"]
mod rezero;

use std::time::Duration;

use optalign::link::framed::{FrameReader, write_frame};
use optalign::link::{ClientError, Endpoint, Event};
use optalign::peer::TimeMode;
use optalign_hil_tests::{SimSetup, Target, configure_backlash};
use optalign_protocol::*;
use rand::{Rng, SeedableRng};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpStream;

fn values(pairs: &[(u8, i32)]) -> Vec<AxisValue> {
    pairs
        .iter()
        .map(|&(axis, steps)| AxisValue { axis, steps })
        .collect()
}

async fn positions(client: &optalign::link::Client) -> Vec<i32> {
    client
        .status()
        .await
        .unwrap()
        .axes
        .iter()
        .map(|a| a.position)
        .collect()
}

/// A raw TCP connection speaking frames by hand.
struct Raw {
    reader: FrameReader<tokio::io::ReadHalf<TcpStream>, PeerMessage>,
    writer: tokio::io::WriteHalf<TcpStream>,
}

impl Raw {
    async fn connect(endpoint: &Endpoint) -> Self {
        let Endpoint::Tcp { host, port } = endpoint else {
            panic!("raw frames need TCP")
        };
        let stream = TcpStream::connect((host.as_str(), *port)).await.unwrap();
        let (read, writer) = tokio::io::split(stream);
        Self {
            reader: FrameReader::new(read),
            writer,
        }
    }

    async fn send(&mut self, id: u32, command: Command) {
        write_frame(
            &mut self.writer,
            &Request {
                id: RequestId(id),
                command,
            },
        )
        .await
        .unwrap();
    }

    async fn send_bytes(&mut self, bytes: &[u8]) {
        self.writer.write_all(bytes).await.unwrap();
    }

    async fn next(&mut self) -> PeerMessage {
        tokio::time::timeout(Duration::from_secs(3), self.reader.next())
            .await
            .expect("peer answered in time")
            .unwrap()
            .expect("connection open")
            .expect("peer frames are valid")
    }

    async fn reply(&mut self, id: u32) -> Reply {
        loop {
            if let PeerMessage::Reply { id: got, reply } = self.next().await
                && got.0 == id
            {
                return reply;
            }
        }
    }
}

#[tokio::test]
async fn handshake_identifies_the_peer_over_tcp_and_serial() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    let client = target.client().await.unwrap();
    let identity = client.identity();
    assert_eq!(identity.protocol_version, PROTOCOL_VERSION);
    assert!(identity.axes >= 1);
    if let Some(serial) = &target.serial {
        let serial_client = optalign::link::Client::connect(serial.clone(), Default::default())
            .await
            .unwrap();
        assert_eq!(serial_client.identity().board_id, identity.board_id);
        assert!(serial_client.status().await.unwrap().session.trusted_link);
    }
}

#[tokio::test]
async fn a_mismatched_version_is_refused_by_the_peer_naming_both_versions() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    if !matches!(target.endpoint, Endpoint::Tcp { .. }) {
        return eprintln!("skipped: raw frames need a TCP target");
    }
    let mut raw = Raw::connect(&target.endpoint).await;
    raw.send(
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION + 41,
        },
    )
    .await;
    match raw.reply(1).await {
        Reply::Refused { error, detail } => {
            assert_eq!(detail, RefusalDetail::ProtocolVersion(PROTOCOL_VERSION));
            assert_eq!(error.code, ErrorCode::VERSION_MISMATCH);
            assert!(
                error.reason.contains(&PROTOCOL_VERSION.to_string()),
                "{}",
                error.reason
            );
            assert!(
                error.reason.contains(&(PROTOCOL_VERSION + 41).to_string()),
                "{}",
                error.reason
            );
        }
        other => panic!("expected a version error, got {other:?}"),
    }
    // Nothing but Hello is served before a successful handshake.
    raw.send(
        2,
        Command::MoveBy {
            deltas: values(&[(0, 10)]).into_iter().collect(),
        },
    )
    .await;
    assert!(
        matches!(raw.reply(2).await, Reply::Error(e) if e.code == ErrorCode::HANDSHAKE_REQUIRED)
    );
}

#[tokio::test]
async fn the_client_refuses_a_peer_of_another_version() {
    // A fake controller that answers every Hello with version 99.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    tokio::spawn(async move {
        let (stream, _) = listener.accept().await.unwrap();
        let (read, mut write) = tokio::io::split(stream);
        let mut reader = FrameReader::<_, Request>::new(read);
        while let Ok(Some(Ok(request))) = reader.next().await {
            let identity = Identity {
                protocol_version: 99,
                firmware_version: "9.9.9".try_into().unwrap(),
                board: "future".try_into().unwrap(),
                board_id: 1,
                axes: 1,
                capabilities: Capabilities(0),
                boot_nonce: 1,
            };
            let reply = PeerMessage::Reply {
                id: request.id,
                reply: Reply::Hello(identity),
            };
            write_frame(&mut write, &reply).await.unwrap();
        }
    });
    let endpoint = Endpoint::Tcp {
        host: "127.0.0.1".into(),
        port,
    };
    let error = optalign::link::Client::connect(endpoint, Default::default())
        .await
        .err()
        .unwrap();
    let text = error.to_string();
    assert!(
        matches!(
            error,
            ClientError::VersionMismatch {
                theirs: Some(99),
                ..
            }
        ),
        "{text}"
    );
    assert!(
        text.contains("99") && text.contains(&PROTOCOL_VERSION.to_string()),
        "{text}"
    );
}

async fn moves_land_exactly(target: &Target, client: &optalign::link::Client) {
    let report = client
        .move_to(&values(&[(0, 2000), (1, -1500)]))
        .await
        .unwrap();
    assert_eq!(report.outcome, MoveOutcome::Completed);
    assert_eq!(&report.positions[..2], &[2000, -1500]);
    let report = client
        .move_by(&values(&[(0, -500), (2, 300)]))
        .await
        .unwrap();
    assert_eq!(&report.positions[..3], &[1500, -1500, 300]);
    assert_eq!(&positions(client).await[..3], &[1500, -1500, 300]);
    if target.truth_available("true shaft check") {
        assert_eq!(&target.shafts()[..3], &[1500, -1500, 300]);
    }
}

#[tokio::test]
async fn absolute_relative_and_multi_axis_moves_land_exactly_over_tcp() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    let client = target.client().await.unwrap();
    moves_land_exactly(&target, &client).await;
}

#[tokio::test]
async fn absolute_relative_and_multi_axis_moves_land_exactly_over_the_pty() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    let Ok(client) = target.serial_client().await else {
        return eprintln!("skipped: the target has no serial link");
    };
    moves_land_exactly(&target, &client).await;
}

#[tokio::test]
async fn coordinated_moves_finish_together() {
    let target = Target::acquire(SimSetup {
        time: TimeMode::Scaled(4.0),
        ..SimSetup::default()
    })
    .await
    .unwrap();
    let client = target.client().await.unwrap();
    let mut events = client.events();
    let id = client.next_request_id();
    let command = Command::MoveTo {
        targets: values(&[(0, 1600), (1, 200)]).into_iter().collect(),
    };
    let started = tokio::time::Instant::now();
    let reply = client.request_with_id(id, command).await.unwrap();
    let Reply::MoveStarted { duration_ms } = reply else {
        panic!("{reply:?}")
    };
    // Halfway through, both axes are still moving, each part of the way.
    tokio::time::sleep(Duration::from_millis(u64::from(duration_ms) / 8)).await;
    let status = client.status().await.unwrap();
    assert!(status.axes[0].moving && status.axes[1].moving, "{status:?}");
    let (a, b) = (status.axes[0].position, status.axes[1].position);
    assert!(a > 0 && a < 1600 && b > 0 && b < 200, "{a} {b}");
    loop {
        if let Ok(Event::Notification(Notification::MoveFinished { request, .. })) =
            events.recv().await
            && request == id
        {
            break;
        }
    }
    assert!(
        started.elapsed() < Duration::from_millis(u64::from(duration_ms)),
        "time scale 4 runs faster than real time"
    );
}

fn backlash_setup() -> SimSetup {
    SimSetup {
        backlash: 40,
        ..SimSetup::default()
    }
}

/// Runs 100 random moves with reversals on axis 0 and returns |true shaft - target| for each.
async fn random_move_errors(
    target: &Target,
    client: &optalign::link::Client,
    seed: u64,
) -> Vec<i32> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let mut errors = Vec::new();
    let mut position = positions(client).await[0];
    for _ in 0..100 {
        let delta = rng.random_range(50..3000) * if rng.random_bool(0.5) { 1 } else { -1 };
        position += delta;
        let report = client.move_to(&values(&[(0, position)])).await.unwrap();
        assert_eq!(
            report.positions[0], position,
            "logical position never includes compensation"
        );
        errors.push((target.shafts()[0] - position).abs());
    }
    errors
}

#[tokio::test]
async fn one_sided_compensation_lands_the_true_shaft_on_target_every_time() {
    let target = Target::acquire(backlash_setup()).await.unwrap();
    if !target.truth_available("backlash accuracy") {
        return;
    }
    let client = target.client().await.unwrap();
    configure_backlash(&client, 0, 40, BacklashMode::OneSided)
        .await
        .unwrap();
    let errors = random_move_errors(&target, &client, 1).await;
    assert!(errors.iter().all(|&e| e == 0), "errors: {errors:?}");
}

#[tokio::test]
async fn take_up_compensation_lands_the_true_shaft_on_target_every_time() {
    let target = Target::acquire(backlash_setup()).await.unwrap();
    if !target.truth_available("backlash accuracy") {
        return;
    }
    let client = target.client().await.unwrap();
    configure_backlash(&client, 0, 40, BacklashMode::TakeUp)
        .await
        .unwrap();
    // After power-up the firmware cannot know where the gear sits in its dead band, so the
    // first take-up move may shift the origin by up to the backlash; re-zero against the
    // true shaft (as a homing switch would) once the slack is known.
    client.move_by(&values(&[(0, 200)])).await.unwrap();
    let shaft = target.shafts()[0];
    client
        .command_ok(Command::SetPosition {
            axis: 0,
            position: shaft,
        })
        .await
        .unwrap();
    let errors = random_move_errors(&target, &client, 2).await;
    assert!(errors.iter().all(|&e| e == 0), "errors: {errors:?}");
}

#[tokio::test]
async fn without_compensation_the_error_is_the_backlash() {
    let target = Target::acquire(backlash_setup()).await.unwrap();
    if !target.truth_available("backlash accuracy") {
        return;
    }
    let client = target.client().await.unwrap();
    configure_backlash(&client, 0, 0, BacklashMode::Off)
        .await
        .unwrap();
    let errors = random_move_errors(&target, &client, 3).await;
    assert!(
        errors.iter().all(|&e| e == 0 || e == 40),
        "errors: {errors:?}"
    );
    let off = errors.iter().filter(|&&e| e == 40).count();
    assert!(
        off >= 40,
        "about half the moves end on the wrong side of the dead band: {off} of 100"
    );
}

#[tokio::test]
async fn moves_smaller_than_the_backlash_still_land() {
    let target = Target::acquire(backlash_setup()).await.unwrap();
    if !target.truth_available("small-move accuracy") {
        return;
    }
    let client = target.client().await.unwrap();
    for mode in [BacklashMode::OneSided, BacklashMode::TakeUp] {
        configure_backlash(&client, 0, 40, mode).await.unwrap();
        client.move_by(&values(&[(0, 100)])).await.unwrap();
        for delta in [-5, 3, -1, 1, 1, -39, 20, -7, 39, -2] {
            let target_position = positions(&client).await[0] + delta;
            client.move_by(&values(&[(0, delta)])).await.unwrap();
            assert_eq!(
                target.shafts()[0],
                target_position,
                "{mode:?} move by {delta}"
            );
        }
    }
}

#[tokio::test]
async fn targets_outside_soft_limits_are_rejected_and_nothing_moves() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    let client = target.client().await.unwrap();
    let mut config = client.get_config(1).await.unwrap();
    config.limits = SoftLimits {
        min: -1000,
        max: 1000,
    };
    client
        .command_ok(Command::SetConfig { axis: 1, config })
        .await
        .unwrap();
    let before = positions(&client).await;
    let error = client
        .move_to(&values(&[(0, 500), (1, 1001)]))
        .await
        .unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::OUT_OF_LIMITS), "{error}");
    assert!(error.to_string().contains("1001"), "{error}");
    let error = client.move_to(&values(&[(9, 5)])).await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::UNKNOWN_AXIS), "{error}");
    assert_eq!(
        positions(&client).await,
        before,
        "a rejected move moves no axis at all"
    );
}

async fn start_long_move(
    client: &optalign::link::Client,
) -> (RequestId, tokio::sync::broadcast::Receiver<Event>) {
    let events = client.events();
    let id = client.next_request_id();
    let command = Command::MoveTo {
        targets: values(&[(0, 20_000), (1, 10_000)]).into_iter().collect(),
    };
    assert!(matches!(
        client.request_with_id(id, command).await.unwrap(),
        Reply::MoveStarted { .. }
    ));
    tokio::time::sleep(Duration::from_millis(300)).await;
    (id, events)
}

async fn finished(
    events: &mut tokio::sync::broadcast::Receiver<Event>,
    id: RequestId,
) -> (MoveOutcome, Vec<i32>) {
    loop {
        let event = tokio::time::timeout(Duration::from_secs(10), events.recv())
            .await
            .unwrap()
            .unwrap();
        if let Event::Notification(Notification::MoveFinished {
            request,
            outcome,
            positions,
        }) = event
            && request == id
        {
            return (outcome, positions.to_vec());
        }
    }
}

#[tokio::test]
async fn stop_decelerates_mid_move_and_positions_stay_consistent() {
    let target = Target::acquire(SimSetup {
        time: TimeMode::Scaled(2.0),
        ..SimSetup::default()
    })
    .await
    .unwrap();
    let client = target.client().await.unwrap();
    let (id, mut events) = start_long_move(&client).await;
    client.command_ok(Command::Stop).await.unwrap();
    let (outcome, stopped_at) = finished(&mut events, id).await;
    assert_eq!(outcome, MoveOutcome::Stopped);
    assert!(
        stopped_at[0] > 0 && stopped_at[0] < 20_000,
        "{stopped_at:?}"
    );
    let status = client.status().await.unwrap();
    assert!(status.axes.iter().all(|a| !a.moving));
    assert_eq!(positions(&client).await, stopped_at);
    if target.truth_available("stop truth") {
        assert_eq!(target.shafts()[..2], stopped_at[..2]);
    }
}

#[tokio::test]
async fn emergency_stop_halts_at_once_cuts_the_coils_and_latches() {
    let target = Target::acquire(SimSetup {
        time: TimeMode::Scaled(2.0),
        ..SimSetup::default()
    })
    .await
    .unwrap();
    let client = target.client().await.unwrap();
    let (id, mut events) = start_long_move(&client).await;
    client.command_ok(Command::EmergencyStop).await.unwrap();
    let (outcome, stopped_at) = finished(&mut events, id).await;
    assert_eq!(outcome, MoveOutcome::EmergencyStopped);
    let status = client.status().await.unwrap();
    assert!(status.emergency_stopped);
    assert!(
        status.axes.iter().all(|a| !a.moving && !a.powered),
        "{status:?}"
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(
        positions(&client).await,
        stopped_at,
        "nothing moves after an emergency stop"
    );
    if let Some(sim) = &target.sim {
        assert!(!sim.core().coils_powered(0), "the mount sees its coils off");
    }
    // Moves are refused until the latch is cleared.
    let error = client.move_by(&values(&[(0, 10)])).await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::EMERGENCY_STOPPED), "{error}");
    assert_eq!(positions(&client).await, stopped_at);
    client.command_ok(Command::ClearEmergency).await.unwrap();
    assert!(!client.status().await.unwrap().emergency_stopped);
    client.move_by(&values(&[(0, 10)])).await.unwrap();
    assert_eq!(positions(&client).await[0], stopped_at[0] + 10);
}

#[tokio::test]
async fn a_retransmitted_move_moves_once() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    let client = target.client().await.unwrap();
    let id = client.next_request_id();
    let command = Command::MoveBy {
        deltas: values(&[(0, 100)]).into_iter().collect(),
    };
    client.run_move_with_id(id, command.clone()).await.unwrap();
    // The same request again (as after a lost reply): answered, not executed.
    let reply = client.request_with_id(id, command).await.unwrap();
    assert!(matches!(reply, Reply::MoveStarted { .. }), "{reply:?}");
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(positions(&client).await[0], 100);
    // Even from a new connection.
    let other = target.client().await.unwrap();
    other
        .request_with_id(
            id,
            Command::MoveBy {
                deltas: values(&[(0, 100)]).into_iter().collect(),
            },
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(positions(&other).await[0], 100);
}

#[tokio::test]
async fn bad_frames_get_errors_and_the_connection_survives() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    if !matches!(target.endpoint, Endpoint::Tcp { .. }) {
        return eprintln!("skipped: raw frames need a TCP target");
    }
    let client = target.client().await.unwrap();
    let before = positions(&client).await;
    let mut raw = Raw::connect(&target.endpoint).await;
    raw.send(
        1,
        Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    )
    .await;
    assert!(matches!(raw.reply(1).await, Reply::Hello(_)));

    // Garbage with a delimiter.
    raw.send_bytes(&[0x13, 0x37, 0xff, 0x42, 0x00]).await;
    assert!(matches!(raw.next().await, PeerMessage::LinkError(_)));
    // An oversized frame.
    raw.send_bytes(&vec![0x55; MAX_FRAME * 2]).await;
    raw.send_bytes(&[0]).await;
    assert!(
        matches!(raw.next().await, PeerMessage::LinkError(e) if e.code == ErrorCode::FRAME_TOO_LARGE)
    );
    // A frame with a flipped bit (bad CRC): a move that must not run.
    let mut frame = [0u8; MAX_FRAME];
    let move_request = Request {
        id: RequestId(5),
        command: Command::MoveBy {
            deltas: values(&[(0, 999)]).into_iter().collect(),
        },
    };
    let len = encode_frame(&move_request, &mut frame).unwrap();
    frame[len / 2] ^= 0x10;
    if frame[len / 2] == 0 {
        frame[len / 2] = 0x01;
    }
    raw.send_bytes(&frame[..len]).await;
    assert!(matches!(raw.next().await, PeerMessage::LinkError(_)));
    // A torn frame (first half only), then a fresh delimiter, then a good request.
    let status_len = encode_frame(
        &Request {
            id: RequestId(6),
            command: Command::Status,
        },
        &mut frame,
    )
    .unwrap();
    raw.send_bytes(&frame[..status_len / 2]).await;
    raw.send_bytes(&[0]).await;
    assert!(matches!(raw.next().await, PeerMessage::LinkError(_)));
    raw.send(7, Command::Status).await;
    assert!(
        matches!(raw.reply(7).await, Reply::Status(_)),
        "the connection survives"
    );

    assert_eq!(positions(&client).await, before, "nothing moved");
    if target.truth_available("bad-frame truth") {
        assert!(target.shafts().iter().all(|&s| s == 0));
    }
}

#[tokio::test]
async fn disconnect_mid_move_then_reconnect_reads_a_consistent_state() {
    let target = Target::acquire(SimSetup {
        time: TimeMode::Scaled(4.0),
        ..SimSetup::default()
    })
    .await
    .unwrap();
    let client = target.client().await.unwrap();
    let _ = start_long_move(&client).await;
    drop(client);
    let client = target.client().await.unwrap();
    let status = client.status().await.unwrap();
    assert!(status.axes[0].moving, "the move goes on without the client");
    assert_eq!(status.axes[0].target, 20_000);
    // A new move waits for motion to end through the status fallback.
    let report = client.move_by(&values(&[(2, 5)])).await.unwrap();
    let status = client.status().await.unwrap();
    assert!(status.axes.iter().all(|a| !a.moving));
    assert_eq!(
        report.positions,
        status.axes.iter().map(|a| a.position).collect::<Vec<_>>()
    );
    if target.truth_available("reconnect truth") {
        assert_eq!(target.shafts(), report.positions);
    }
}

#[tokio::test]
async fn a_restarted_peer_restores_positions() {
    if std::env::var(optalign_hil_tests::HIL_ENV).is_ok() {
        return eprintln!("skipped: restarting needs the simulator");
    }
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.json");
    let setup = SimSetup {
        state_file: Some(state.clone()),
        backlash: 20,
        ..SimSetup::default()
    };
    let first = Target::simulated(setup.clone()).await.unwrap();
    let client = first.client().await.unwrap();
    client
        .move_to(&values(&[(0, 1234), (3, -4321)]))
        .await
        .unwrap();
    let shafts = first.shafts();
    drop(client);
    first.sim.as_ref().unwrap().shutdown();
    drop(first);

    let second = Target::simulated(setup).await.unwrap();
    let client = second.client().await.unwrap();
    let status = client.status().await.unwrap();
    assert_eq!(status.axes[0].position, 1234);
    assert_eq!(status.axes[3].position, -4321);
    assert!(
        status.axes.iter().all(|a| !a.powered),
        "coils come back off"
    );
    assert_eq!(
        second.shafts(),
        shafts,
        "the mirrors are where they were left"
    );
}

#[tokio::test]
async fn without_the_right_key_nothing_moves_over_tcp() {
    let target = Target::acquire(SimSetup::default()).await.unwrap();
    if target.key.is_none() {
        return eprintln!("skipped: OPTALIGN_KEY is not set for the board");
    }
    let keyless = target.client_with_key(None).await.unwrap();
    let before = positions(&keyless).await;
    let error = keyless.move_to(&values(&[(0, 777)])).await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::UNAUTHORIZED), "{error}");
    let error = target
        .client_with_key(Some("not-the-key"))
        .await
        .err()
        .unwrap();
    assert!(error.to_string().contains("auth"), "{error}");
    assert_eq!(positions(&keyless).await, before);
    if target.truth_available("key truth") {
        assert!(target.shafts().iter().all(|&s| s == 0));
    }
}

#[tokio::test]
async fn a_peer_without_a_key_refuses_tcp_motion_and_says_how_to_provision() {
    if std::env::var(optalign_hil_tests::HIL_ENV).is_ok() {
        return eprintln!("skipped: needs an unprovisioned simulator");
    }
    let target = Target::simulated(SimSetup {
        key: None,
        ..SimSetup::default()
    })
    .await
    .unwrap();
    let client = target.client().await.unwrap();
    let error = client.move_to(&values(&[(0, 10)])).await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::NO_KEY));
    assert!(error.to_string().contains("provision"), "{error}");
    // Provision over the trusted serial link, then the network client can move.
    let serial = target.serial_client().await.unwrap();
    let board_id = serial.identity().board_id;
    serial
        .command_ok(Command::SetKey {
            key: optalign::link::key::stretch("fresh-key-123", board_id),
        })
        .await
        .unwrap();
    let error = serial
        .command_ok(Command::SetKey {
            key: optalign::link::key::stretch("x", board_id),
        })
        .await;
    assert!(error.is_ok(), "serial stays trusted");
    let net = target.client_with_key(Some("x")).await.unwrap();
    assert!(net.move_to(&values(&[(0, 10)])).await.is_ok());
    // Keys are never accepted over the network.
    let error = net
        .command_ok(Command::SetKey { key: [0; 32] })
        .await
        .unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::SERIAL_ONLY));
}
