//! Hostile clients against the simulated peer on 127.0.0.1, while a client with the key
//! moves and anyone stops: silent connections that reconnect whenever they are closed (four
//! and six of them, on four slots), a client that sends requests and never reads the
//! replies, one that sends a byte a second, and one that sends oversized frames. Each
//! authenticated move (a fresh connection each time, as `optalign move` makes) and each
//! keyless `optalign stop --emergency` must get through within one second, checked against
//! the peer's true shafts and coils.
//!
//! `cargo test -p optalign --test integration hostile_clients:: -- --nocapture` prints the figures
//! docs/reliability.md quotes.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use optalign::link::{AccessKey, Client, ClientOptions, Endpoint};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_protocol::{
    AxisValue, Command, MAX_FRAME, MoveOutcome, PROTOCOL_VERSION, PeerMessage, Reply, Request,
    RequestId, encode_frame,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};
use tokio::task::JoinSet;

use crate::BIN;
const KEY: &str = "hostile-clients-key";
const WITHIN: Duration = Duration::from_secs(1);

async fn peer() -> (Arc<SimPeer>, SocketAddr) {
    SimPeer::start_on_loopback(&PeerOptions {
        axes: 2,
        key: Some(KEY.into()),
        time: TimeMode::Instant,
        max_clients: 4,
        ..PeerOptions::default()
    })
    .await
    .unwrap()
}

fn endpoint(address: SocketAddr) -> Endpoint {
    format!("tcp://{address}").parse().unwrap()
}

/// The attackers, stopped when dropped.
struct Attack {
    tasks: JoinSet<()>,
    running: Arc<AtomicBool>,
    connects: Arc<AtomicUsize>,
}

impl Attack {
    fn new() -> Self {
        Self {
            tasks: JoinSet::new(),
            running: Arc::new(AtomicBool::new(true)),
            connects: Arc::default(),
        }
    }

    /// A client that connects, says nothing, and reconnects whenever it is closed.
    fn silent_holder(&mut self, address: SocketAddr) {
        let (running, connects) = (self.running.clone(), self.connects.clone());
        self.tasks.spawn(async move {
            while running.load(Ordering::Relaxed) {
                if let Ok(mut stream) = TcpStream::connect(address).await {
                    connects.fetch_add(1, Ordering::Relaxed);
                    let mut byte = [0u8; 64];
                    while let Ok(1..) = stream.read(&mut byte).await {}
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
        });
    }

    /// A client that floods `Status` requests and never reads a reply; it reconnects when
    /// closed. Counts the connections the peer closed on it.
    fn never_reads(&mut self, address: SocketAddr, closed: Arc<AtomicUsize>) {
        let running = self.running.clone();
        self.tasks.spawn(async move {
            let mut frames = frame(1, hello());
            for id in 2..4000 {
                frames.extend(frame(id, Command::Status));
            }
            while running.load(Ordering::Relaxed) {
                let socket = TcpSocket::new_v4().unwrap();
                socket.set_recv_buffer_size(4096).unwrap();
                let Ok(mut stream) = socket.connect(address).await else {
                    continue;
                };
                while running.load(Ordering::Relaxed) {
                    let written =
                        tokio::time::timeout(Duration::from_secs(1), stream.write_all(&frames))
                            .await;
                    if let Ok(Err(_)) = written {
                        closed.fetch_add(1, Ordering::Relaxed);
                        break;
                    }
                }
            }
        });
    }

    /// A client that sends a `Hello` one byte a second, over and over.
    fn one_byte_a_second(&mut self, address: SocketAddr) {
        let running = self.running.clone();
        self.tasks.spawn(async move {
            let hello = frame(1, hello());
            while running.load(Ordering::Relaxed) {
                let Ok(mut stream) = TcpStream::connect(address).await else {
                    continue;
                };
                for byte in hello.iter().cycle() {
                    if stream.write_all(&[*byte]).await.is_err() || !running.load(Ordering::Relaxed)
                    {
                        break;
                    }
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
            }
        });
    }

    /// A client that sends frames longer than `MAX_FRAME`, reading what comes back.
    fn oversized_frames(&mut self, address: SocketAddr, answered: Arc<AtomicUsize>) {
        let running = self.running.clone();
        self.tasks.spawn(async move {
            let mut garbage = vec![0x55u8; 4 * MAX_FRAME];
            garbage.push(0);
            while running.load(Ordering::Relaxed) {
                let Ok(stream) = TcpStream::connect(address).await else {
                    continue;
                };
                let (mut read, mut write) = stream.into_split();
                let reader = tokio::spawn({
                    let answered = answered.clone();
                    async move {
                        let mut buf = [0u8; 1024];
                        while let Ok(1..) = read.read(&mut buf).await {
                            answered.fetch_add(1, Ordering::Relaxed);
                        }
                    }
                });
                while running.load(Ordering::Relaxed) && write.write_all(&garbage).await.is_ok() {
                    tokio::time::sleep(Duration::from_millis(20)).await;
                }
                reader.abort();
            }
        });
    }
}

impl Drop for Attack {
    fn drop(&mut self) {
        self.running.store(false, Ordering::Relaxed);
        self.tasks.abort_all();
    }
}

fn hello() -> Command {
    Command::Hello {
        protocol_version: PROTOCOL_VERSION,
    }
}

fn frame(id: u32, command: Command) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(
        &Request {
            id: RequestId(id),
            command,
        },
        &mut out,
    )
    .unwrap();
    out[..len].to_vec()
}

/// What got through while under attack.
#[derive(Default, Debug)]
struct Figures {
    moves: usize,
    stops: usize,
    slowest_move: Duration,
    slowest_stop: Duration,
}

/// A move on a fresh connection with the key, as `optalign move` makes it; returns how long
/// it took from connecting to its end.
async fn keyed_move(address: SocketAddr, axis: u8, steps: i32) -> Duration {
    let started = Instant::now();
    let client = Client::connect(
        endpoint(address),
        ClientOptions {
            key: Some(AccessKey::passphrase(KEY)),
            ..ClientOptions::default()
        },
    )
    .await
    .expect("a client with the key gets in");
    let report = client
        .move_by(&[AxisValue { axis, steps }])
        .await
        .expect("the move runs");
    assert_eq!(report.outcome, MoveOutcome::Completed);
    started.elapsed()
}

/// `optalign stop --emergency` without a key; returns how long it took.
async fn keyless_emergency_stop(address: SocketAddr) -> Duration {
    let started = Instant::now();
    let output = tokio::process::Command::new(BIN)
        .args(["stop", "--emergency", "--controller"])
        .arg(format!("tcp://{address}"))
        .env_remove("OPTALIGN_KEY")
        .env("RUST_LOG", "error")
        .output()
        .await
        .unwrap();
    let elapsed = started.elapsed();
    assert!(
        output.status.success(),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    elapsed
}

/// Releases the latch with the key (a fresh connection).
async fn clear_emergency(address: SocketAddr) {
    let client = Client::connect(
        endpoint(address),
        ClientOptions {
            key: Some(AccessKey::passphrase(KEY)),
            ..ClientOptions::default()
        },
    )
    .await
    .unwrap();
    client.command_ok(Command::ClearEmergency).await.unwrap();
}

/// Whether the peer's emergency latch is set, as its serial link reads it.
fn latched(peer: &SimPeer) -> bool {
    peer.serial_request(Command::Status).iter().any(|message| {
        matches!(
            message,
            PeerMessage::Reply {
                reply: Reply::Status(status),
                ..
            } if status.emergency_stopped
        )
    })
}

/// Moves and emergency stops in turn, each checked against the peer's truth.
async fn moves_and_stops(peer: &SimPeer, address: SocketAddr, rounds: i32) -> Figures {
    let mut figures = Figures::default();
    let mut expected = peer.shaft_positions();
    for round in 1..=rounds {
        let steps = 25 * round;
        let took = keyed_move(address, 0, steps).await;
        expected[0] += steps;
        assert_eq!(peer.shaft_positions(), expected, "round {round}");
        assert!(took < WITHIN, "a move took {took:?}");
        figures.moves += 1;
        figures.slowest_move = figures.slowest_move.max(took);

        let took = keyless_emergency_stop(address).await;
        assert!(took < WITHIN, "an emergency stop took {took:?}");
        assert!(
            latched(peer),
            "the emergency stop is latched in round {round}"
        );
        let waited = Instant::now();
        while peer.core().coils_powered(0) && waited.elapsed() < WITHIN {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        assert!(
            !peer.core().coils_powered(0),
            "coils off after the emergency stop"
        );
        figures.stops += 1;
        figures.slowest_stop = figures.slowest_stop.max(took);
        clear_emergency(address).await;
    }
    figures
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_reconnecting_holders_keep_out_neither_moves_nor_emergency_stops() {
    for holders in [4, 6] {
        let (peer, address) = peer().await;
        let mut attack = Attack::new();
        for _ in 0..holders {
            attack.silent_holder(address);
        }
        // Every slot held, every holder past the grace a newcomer gets.
        tokio::time::sleep(Duration::from_millis(400)).await;
        assert_eq!(
            peer.network_clients(),
            holders.min(5),
            "four slots, and the stop-only place"
        );
        let started = Instant::now();
        let figures = moves_and_stops(&peer, address, 4).await;
        let connects = attack.connects.load(Ordering::Relaxed);
        println!(
            "{holders} silent reconnecting holders on 4 slots: {}/4 moves and {}/4 emergency \
             stops through in {:.2} s; slowest move {:.0} ms, slowest stop {:.0} ms; \
             {connects} holder connections",
            figures.moves,
            figures.stops,
            started.elapsed().as_secs_f64(),
            figures.slowest_move.as_secs_f64() * 1e3,
            figures.slowest_stop.as_secs_f64() * 1e3,
        );
        drop(attack);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn non_readers_slow_senders_and_oversized_frames_keep_out_neither_moves_nor_stops() {
    let (peer, address) = peer().await;
    let mut attack = Attack::new();
    let closed_non_readers = Arc::new(AtomicUsize::new(0));
    let answered_garbage = Arc::new(AtomicUsize::new(0));
    attack.never_reads(address, closed_non_readers.clone());
    attack.one_byte_a_second(address);
    attack.oversized_frames(address, answered_garbage.clone());
    attack.silent_holder(address);
    tokio::time::sleep(Duration::from_millis(400)).await;

    let figures = moves_and_stops(&peer, address, 3).await;
    assert_eq!((figures.moves, figures.stops), (3, 3));

    // The client that never reads was closed at its send deadline (2 s), and oversized
    // frames were answered (frame-too-large), not taken for requests.
    let waited = Instant::now();
    while closed_non_readers.load(Ordering::Relaxed) == 0 && waited.elapsed() < WITHIN * 6 {
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    println!(
        "non-reader closed {} times, {:?} after the moves",
        closed_non_readers.load(Ordering::Relaxed),
        waited.elapsed()
    );
    assert!(
        closed_non_readers.load(Ordering::Relaxed) > 0,
        "a client that never reads its replies holds its connection"
    );
    assert!(answered_garbage.load(Ordering::Relaxed) > 0);
    assert_eq!(peer.shaft_positions()[1], 0, "nothing else moved");
    println!("mixed attack: {figures:?}");
}
