//! When things go wrong, against simulated peers on 127.0.0.1: the emergency latch through
//! the `optalign` command, a peer killed in the middle of a move, a peer restarted between
//! a move and its retransmission or during the move, and a move's end the client missed.

use std::net::SocketAddr;
use std::path::Path;
use std::process::{Output, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use optalign::link::{Client, ClientError, ClientOptions, Endpoint, Unknown};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_protocol::{AxisValue, Command, Faults, MoveOutcome, Reply, Request, RequestId};
use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::{TcpListener, TcpStream};
use tokio::process::Child;
use tokio::sync::watch;

use crate::BIN;
const KEY: &str = "trust-test-key";

/// Runs `optalign ARGS --controller URL --key KEY`.
async fn optalign(url: &str, args: &[&str]) -> Output {
    tokio::process::Command::new(BIN)
        .args(args)
        .args(["--controller", url, "--key", KEY])
        .env("RUST_LOG", "error")
        .kill_on_drop(true)
        .output()
        .await
        .unwrap()
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

/// A simulated peer with the test key on a loopback port.
async fn peer(time: TimeMode, state_file: Option<&Path>) -> (Arc<SimPeer>, SocketAddr) {
    let (peer, address) = SimPeer::start_on_loopback(&PeerOptions {
        axes: 2,
        key: Some(KEY.into()),
        time,
        state_file: state_file.map(Path::to_path_buf),
        ..PeerOptions::default()
    })
    .await
    .unwrap();
    (peer, address)
}

#[tokio::test]
async fn an_emergency_stop_refuses_moves_until_cleared() {
    let (peer, address) = peer(TimeMode::Instant, None).await;
    let url = format!("tcp://{address}");
    let stop = optalign(&url, &["stop", "--emergency"]).await;
    assert!(stop.status.success(), "{}", text(&stop));
    assert!(
        text(&stop).contains("optalign clear-emergency"),
        "{}",
        text(&stop)
    );

    let refused = optalign(&url, &["move", "0=100"]).await;
    assert!(!refused.status.success(), "{}", text(&refused));
    let message = text(&refused);
    assert!(message.contains("emergency-stopped (43)"), "{message}");
    assert!(message.contains("optalign clear-emergency"), "{message}");
    assert_eq!(peer.shaft_positions(), [0, 0], "nothing moved");

    let cleared = optalign(&url, &["clear-emergency"]).await;
    assert!(cleared.status.success(), "{}", text(&cleared));
    let moved = optalign(&url, &["move", "0=100"]).await;
    assert!(moved.status.success(), "{}", text(&moved));
    assert!(
        text(&moved).contains("move completed: 0=100"),
        "{}",
        text(&moved)
    );
    assert_eq!(peer.shaft_positions(), [100, 0]);
}

/// `optalign peer` in its own process, keeping its state in `state`; returns it and its URL.
async fn peer_process(state: &Path) -> (Child, String) {
    let mut child = tokio::process::Command::new(BIN)
        .args([
            "peer",
            "--listen",
            "127.0.0.1:0",
            "--axes",
            "2",
            "--key",
            KEY,
        ])
        .arg("--state")
        .arg(state)
        .env("RUST_LOG", "error")
        .stdout(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(child.stdout.take().unwrap()).lines();
    loop {
        let line = tokio::time::timeout(Duration::from_secs(20), lines.next_line())
            .await
            .expect("the peer starts")
            .unwrap()
            .expect("the peer prints its address");
        if let Some(url) = line.strip_prefix("listening on ") {
            return (child, url.to_owned());
        }
    }
}

fn client_options() -> ClientOptions {
    ClientOptions {
        key: Some(optalign::link::AccessKey::passphrase(KEY)),
        ..ClientOptions::default()
    }
}

#[tokio::test]
async fn a_peer_killed_mid_move_comes_back_with_the_position_lost_until_re_zeroed() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.json");
    let (mut first, url) = peer_process(&state).await;
    let client = Client::connect(url.parse().unwrap(), client_options())
        .await
        .unwrap();
    let long = Command::MoveTo {
        targets: [AxisValue {
            axis: 0,
            steps: 20_000,
        }]
        .into_iter()
        .collect(),
    };
    client.request(long).await.unwrap();
    // Steps are being made, then the power goes.
    for _ in 0..100 {
        if client.status().await.unwrap().axes[0].position > 0 {
            break;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert!(client.status().await.unwrap().axes[0].moving);
    first.kill().await.unwrap();
    drop(client);
    // The mounts are kept apart from the flash: the shaft stopped where the power went.
    let mounts: Vec<optalign_firmware::sim::MountModel> =
        serde_json::from_slice(&std::fs::read(dir.path().join("peer.json.mounts.json")).unwrap())
            .unwrap();
    let shaft = mounts[0].mirror_position();
    assert!(
        (1..20_000).contains(&shaft),
        "the shaft stopped mid-way: {shaft}"
    );

    let (_second, url) = peer_process(&state).await;
    let status = optalign(&url, &["status"]).await;
    assert!(status.status.success(), "{}", text(&status));
    let table = text(&status);
    assert!(
        table.contains("reset during a move") && table.contains("POSITION LOST on axis 0:"),
        "{table}"
    );
    let row = table
        .lines()
        .find(|l| l.trim_start().starts_with("0 "))
        .unwrap();
    assert!(row.ends_with("position-lost"), "{table}");
    // The same in words for scripts (schema optalign.status/1), no bit masks.
    let json = optalign(&url, &["status", "--json"]).await;
    let report: serde_json::Value = serde_json::from_slice(&json.stdout).unwrap();
    assert_eq!(report["schema"], "optalign.status/1");
    assert_eq!(report["boot"], "interrupted-move");
    assert_eq!(report["positions_lost"], serde_json::json!([0]));
    assert_eq!(
        report["axes"][0]["faults"],
        serde_json::json!(["position-lost"])
    );
    assert_eq!(report["axes"][1]["faults"], serde_json::json!([]));

    let refused = optalign(&url, &["move", "0=100"]).await;
    assert!(!refused.status.success(), "{}", text(&refused));
    let message = text(&refused);
    assert!(message.contains("axis-fault (44)"), "{message}");
    assert!(
        message.contains("optalign set-position AXIS=STEPS"),
        "{message}"
    );
    // Axis 1 did not move, so it keeps its position.
    let other = optalign(&url, &["move", "1=50"]).await;
    assert!(other.status.success(), "{}", text(&other));

    let zeroed = optalign(&url, &["set-position", "0=0"]).await;
    assert!(zeroed.status.success(), "{}", text(&zeroed));
    let moved = optalign(&url, &["move", "0=100"]).await;
    assert!(
        text(&moved).contains("move completed: 0=100 1=50"),
        "{}",
        text(&moved)
    );
    let status = text(&optalign(&url, &["status"]).await);
    assert!(!status.contains("POSITION LOST"), "{status}");
}

/// A loopback relay to the current peer that can hold back the peer's answers and cut
/// every connection, as a controller that restarts does.
struct Relay {
    address: SocketAddr,
    upstream: Arc<Mutex<SocketAddr>>,
    hold: Arc<AtomicBool>,
    cut: watch::Sender<u32>,
}

impl Relay {
    async fn start(upstream: SocketAddr) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let relay = Self {
            address: listener.local_addr().unwrap(),
            upstream: Arc::new(Mutex::new(upstream)),
            hold: Arc::default(),
            cut: watch::channel(0).0,
        };
        let (upstream, hold, cut) = (
            relay.upstream.clone(),
            relay.hold.clone(),
            relay.cut.clone(),
        );
        tokio::spawn(async move {
            while let Ok((client, _)) = listener.accept().await {
                let to = *upstream.lock().unwrap();
                if let Ok(peer) = TcpStream::connect(to).await {
                    tokio::spawn(forward(client, peer, hold.clone(), cut.subscribe()));
                }
            }
        });
        relay
    }

    fn endpoint(&self) -> Endpoint {
        format!("tcp://{}", self.address).parse().unwrap()
    }

    /// Restarts the controller behind the relay, as a reset does: `first` shuts down, a new
    /// peer starts from the same state file, the relay points at it, lets answers through
    /// again and cuts every connection.
    async fn restart(&self, first: &SimPeer, time: TimeMode, state: &Path) -> Arc<SimPeer> {
        first.shutdown();
        let (second, address) = peer(time, Some(state)).await;
        *self.upstream.lock().unwrap() = address;
        self.hold.store(false, Ordering::SeqCst);
        self.cut.send_modify(|n| *n += 1);
        second
    }
}

/// Polls `condition` every 5 ms, up to `tries` times; whether it came true.
async fn eventually(tries: usize, mut condition: impl FnMut() -> bool) -> bool {
    for _ in 0..tries {
        if condition() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    condition()
}

/// Copies bytes both ways, dropping the peer's while `hold` is set, until either side
/// closes or the relay cuts.
async fn forward(
    client: TcpStream,
    peer: TcpStream,
    hold: Arc<AtomicBool>,
    mut cut: watch::Receiver<u32>,
) {
    let (mut client_read, mut client_write) = client.into_split();
    let (mut peer_read, mut peer_write) = peer.into_split();
    let (mut up, mut down) = ([0u8; 1024], [0u8; 1024]);
    loop {
        tokio::select! {
            _ = cut.changed() => return,
            read = client_read.read(&mut up) => match read {
                Ok(0) | Err(_) => return,
                Ok(n) => {
                    if peer_write.write_all(&up[..n]).await.is_err() {
                        return;
                    }
                }
            },
            read = peer_read.read(&mut down) => match read {
                Ok(0) | Err(_) => return,
                Ok(n) => {
                    if !hold.load(Ordering::SeqCst) && client_write.write_all(&down[..n]).await.is_err() {
                        return;
                    }
                }
            },
        }
    }
}

#[tokio::test]
async fn a_move_whose_controller_restarted_before_answering_runs_once_and_is_unknown() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.json");
    let (first, address) = peer(TimeMode::Instant, Some(&state)).await;
    let relay = Relay::start(address).await;
    let client = relayed_client(&relay, Some(Duration::from_millis(500))).await;
    let booted = client.boot_nonce();
    // The move runs, but its answer is lost on the way back...
    relay.hold.store(true, Ordering::SeqCst);
    let command = Command::MoveBy {
        deltas: [AxisValue {
            axis: 0,
            steps: 500,
        }]
        .into_iter()
        .collect(),
    };
    let moving = client.run_move_with_id(client.next_request_id(), command);
    let restart = async {
        eventually(200, || {
            first.shaft_positions()[0] == 500 && !first.core().is_moving()
        })
        .await;
        assert_eq!(first.shaft_positions(), [500, 0], "the move ran");
        // ...and the controller restarts before the client sends it again.
        relay.restart(&first, TimeMode::Instant, &state).await
    };
    let (outcome, second) = tokio::join!(moving, restart);
    let error = outcome.unwrap_err();
    assert!(
        matches!(
            error,
            ClientError::OutcomeUnknown {
                request: "MoveBy",
                why: Unknown::Restarted,
                ..
            }
        ),
        "{error}"
    );
    assert!(
        error
            .to_string()
            .contains(": the controller restarted while it was under way"),
        "{error}"
    );
    assert_ne!(
        client.boot_nonce(),
        booted,
        "the client met the new start-up"
    );
    // It was not sent again: the move happened once.
    tokio::time::sleep(Duration::from_millis(200)).await;
    assert_eq!(second.shaft_positions(), [500, 0]);
    assert_eq!(client.status().await.unwrap().axes[0].position, 500);
    assert!(!second.core().is_moving());
}

/// A move of axis 0 far enough to take a while.
fn long_move() -> Command {
    Command::MoveTo {
        targets: [AxisValue {
            axis: 0,
            steps: 20_000,
        }]
        .into_iter()
        .collect(),
    }
}

/// Waits until `peer` has made steps of the move in progress.
async fn under_way(peer: &SimPeer) {
    assert!(
        eventually(500, || peer.core().is_moving()
            && peer.shaft_positions()[0] > 0)
        .await,
        "the move never got under way"
    );
}

/// A client with the test key through `relay`, with its own request timeout if given.
async fn relayed_client(relay: &Relay, request_timeout: Option<Duration>) -> Client {
    let defaults = client_options();
    let options = ClientOptions {
        request_timeout: request_timeout.unwrap_or(defaults.request_timeout),
        ..defaults
    };
    Client::connect(relay.endpoint(), options).await.unwrap()
}

#[tokio::test]
async fn a_move_whose_controller_went_silent_is_reported_as_possibly_run() {
    let (first, address) = peer(TimeMode::Instant, None).await;
    let relay = Relay::start(address).await;
    let client = relayed_client(&relay, Some(Duration::from_millis(100))).await;
    // The move reaches the controller, and nothing comes back (the controller died).
    relay.hold.store(true, Ordering::SeqCst);
    let id = client.next_request_id();
    let command = Command::MoveBy {
        deltas: [AxisValue {
            axis: 0,
            steps: 300,
        }]
        .into_iter()
        .collect(),
    };
    let error = client.run_move_with_id(id, command).await.unwrap_err();
    assert!(
        matches!(
            error,
            ClientError::OutcomeUnknown {
                request: "MoveBy",
                why: Unknown::Unanswered,
                ..
            }
        ),
        "{error}"
    );
    let text = error.to_string();
    assert!(text.starts_with("outcome unknown: MoveBy"), "{text}");
    assert!(text.contains(&format!("{:#010x}", id.0)), "{text}");
    assert!(text.contains("it may have run"), "{text}");
    assert_eq!(first.shaft_positions()[0], 300, "it did run");
}

#[tokio::test]
async fn a_stop_whose_notification_was_lost_is_reported_as_stopped() {
    let (peer, address) = peer(TimeMode::Scaled(2.0), None).await;
    let relay = Relay::start(address).await;
    let client = relayed_client(&relay, None).await;
    let moving = client.run_move_with_id(client.next_request_id(), long_move());
    let interfere = async {
        under_way(&peer).await;
        // The client hears nothing more while the move is stopped over the serial link...
        relay.hold.store(true, Ordering::SeqCst);
        {
            let mut core = peer.core();
            let mut serial = core.serial_session();
            let stop = Request {
                id: RequestId(77),
                command: Command::Stop,
            };
            let replies = core.handle(&mut serial, &stop);
            assert!(
                matches!(
                    replies.as_slice(),
                    [optalign_protocol::PeerMessage::Reply {
                        reply: Reply::Ok,
                        ..
                    }]
                ),
                "{replies:?}"
            );
        }
        while peer.core().is_moving() {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        // ...and its link drops, taking the MoveFinished with it.
        relay.hold.store(false, Ordering::SeqCst);
        relay.cut.send_modify(|n| *n += 1);
    };
    let (report, ()) = tokio::join!(moving, interfere);
    let report = report.unwrap();
    assert_eq!(report.outcome, MoveOutcome::Stopped);
    let status = client.status().await.unwrap();
    let axis = status.axes[0];
    assert_eq!(report.positions[0], axis.position);
    assert!(axis.position > 0 && axis.position < 20_000, "{axis:?}");
    // Idle, the axis's target is where it stopped: positions alone would say completed.
    assert_eq!(axis.target, axis.position);
}

#[tokio::test]
async fn a_move_cut_short_by_a_restart_is_reported_unknown() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.json");
    let (first, address) = peer(TimeMode::Scaled(1.0), Some(&state)).await;
    let relay = Relay::start(address).await;
    let client = relayed_client(&relay, None).await;
    let moving = client.run_move_with_id(client.next_request_id(), long_move());
    let restart = async {
        under_way(&first).await;
        relay.restart(&first, TimeMode::Scaled(1.0), &state).await
    };
    let (outcome, _second) = tokio::join!(moving, restart);
    let error = outcome.unwrap_err();
    assert!(
        matches!(
            error,
            ClientError::OutcomeUnknown {
                request: "MoveTo",
                why: Unknown::Restarted,
                ..
            }
        ),
        "{error}"
    );
    let status = client.status().await.unwrap();
    assert!(status.axes[0].faults.has(Faults::POSITION_LOST));
}

#[tokio::test]
async fn an_emergency_stop_is_sent_again_to_a_restarted_controller() {
    let dir = tempfile::tempdir().unwrap();
    let state = dir.path().join("peer.json");
    let (first, address) = peer(TimeMode::Instant, Some(&state)).await;
    let relay = Relay::start(address).await;
    let client = relayed_client(&relay, Some(Duration::from_millis(500))).await;
    relay.hold.store(true, Ordering::SeqCst);
    let stopping = client.command_ok(Command::EmergencyStop);
    let restart = async {
        assert!(
            eventually(200, || latched(&first)).await,
            "the first start-up stopped"
        );
        let second = relay.restart(&first, TimeMode::Instant, &state).await;
        assert!(!latched(&second), "a restart forgets the latch");
        second
    };
    let (stopped, _second) = tokio::join!(stopping, restart);
    stopped.unwrap();
    assert!(client.status().await.unwrap().emergency_stopped);
}

/// Whether `peer`'s emergency latch is set, read over an in-process serial session.
fn latched(peer: &SimPeer) -> bool {
    let mut core = peer.core();
    let mut serial = core.serial_session();
    let status = Request {
        id: RequestId(78),
        command: Command::Status,
    };
    match core.handle(&mut serial, &status).as_slice() {
        [
            optalign_protocol::PeerMessage::Reply {
                reply: Reply::Status(status),
                ..
            },
        ] => status.emergency_stopped,
        other => panic!("{other:?}"),
    }
}
