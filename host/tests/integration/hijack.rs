//! Sessions that cannot be hijacked, against simulated peers on 127.0.0.1: the frames of an
//! authenticated session replayed on a new connection, frames forged into a live session, a
//! wrong key refused, counted and backed off, idle strangers closed, `hex:` keys, and a
//! fake controller that cannot seal its answer refused by the client.
//!
//! A recording proxy sits between the client and the peer: it keeps what the client sent,
//! can inject bytes into the client's stream, and stands for a machine on the same network.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use optalign::link::{AccessKey, Client, ClientOptions, Endpoint};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_protocol::auth::session_key;
use optalign_protocol::seal::{Direction, Sealer};
use optalign_protocol::{
    AxisValue, Command, ErrorCode, FrameDecoder, MAX_FRAME, PROTOCOL_VERSION, PeerMessage, Reply,
    Request, RequestId, encode_frame, encode_sealed_frame,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::mpsc;

use crate::BIN;
const KEY: &str = "hijack-test-key";

async fn peer(time: TimeMode) -> (Arc<SimPeer>, SocketAddr) {
    SimPeer::start_on_loopback(&PeerOptions {
        axes: 2,
        key: Some(KEY.into()),
        time,
        max_clients: 3,
        ..PeerOptions::default()
    })
    .await
    .unwrap()
}

fn endpoint(address: SocketAddr) -> Endpoint {
    format!("tcp://{address}").parse().unwrap()
}

async fn client(
    address: SocketAddr,
    key: Option<&str>,
) -> Result<Client, optalign::link::ClientError> {
    Client::connect(
        endpoint(address),
        ClientOptions {
            key: key.map(|key| key.parse::<AccessKey>().expect("a well-formed key")),
            request_timeout: Duration::from_millis(500),
            ..ClientOptions::default()
        },
    )
    .await
}

fn delta(axis: u8, steps: i32) -> [AxisValue; 1] {
    [AxisValue { axis, steps }]
}

/// A proxy for one connection: forwards both ways, records what the client sends (from
/// [`Proxy::record_from_now`]) and injects bytes into the client's stream.
struct Proxy {
    address: SocketAddr,
    recorded: Arc<Mutex<Vec<u8>>>,
    inject: mpsc::UnboundedSender<Vec<u8>>,
}

impl Proxy {
    async fn start(upstream: SocketAddr) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap();
        let recorded = Arc::new(Mutex::new(Vec::new()));
        let (inject, mut injected) = mpsc::unbounded_channel::<Vec<u8>>();
        let record = recorded.clone();
        tokio::spawn(async move {
            let (client, _) = listener.accept().await.unwrap();
            let peer = TcpStream::connect(upstream).await.unwrap();
            let (mut client_read, mut client_write) = client.into_split();
            let (mut peer_read, mut peer_write) = peer.into_split();
            let (mut up, mut down) = ([0u8; 2048], [0u8; 2048]);
            loop {
                tokio::select! {
                    read = client_read.read(&mut up) => match read {
                        Ok(0) | Err(_) => return,
                        Ok(n) => {
                            record.lock().unwrap().extend_from_slice(&up[..n]);
                            if peer_write.write_all(&up[..n]).await.is_err() {
                                return;
                            }
                        }
                    },
                    Some(bytes) = injected.recv() => {
                        if peer_write.write_all(&bytes).await.is_err() {
                            return;
                        }
                    },
                    read = peer_read.read(&mut down) => match read {
                        Ok(0) | Err(_) => return,
                        Ok(n) => {
                            if client_write.write_all(&down[..n]).await.is_err() {
                                return;
                            }
                        }
                    },
                }
            }
        });
        Self {
            address,
            recorded,
            inject,
        }
    }

    fn record_from_now(&self) {
        self.recorded.lock().unwrap().clear();
    }

    /// The whole frames the client sent since recording started, each with its delimiter.
    fn frames(&self) -> Vec<Vec<u8>> {
        let bytes = self.recorded.lock().unwrap().clone();
        bytes
            .split_inclusive(|&b| b == 0)
            .filter(|frame| frame.len() > 1 && frame.ends_with(&[0]))
            .map(<[u8]>::to_vec)
            .collect()
    }

    fn inject(&self, bytes: Vec<u8>) {
        self.inject.send(bytes).unwrap();
    }
}

/// Writes `bytes` on a new raw connection to `address` and collects what comes back
/// until the line stays quiet for a while.
async fn raw_exchange(address: SocketAddr, bytes: &[u8]) -> Vec<PeerMessage> {
    let mut stream = TcpStream::connect(address).await.unwrap();
    stream.write_all(bytes).await.unwrap();
    let mut decoder = FrameDecoder::new();
    let mut messages = Vec::new();
    let mut buf = [0u8; 2048];
    while let Ok(Ok(n)) =
        tokio::time::timeout(Duration::from_millis(400), stream.read(&mut buf)).await
    {
        if n == 0 {
            break;
        }
        decoder.feed::<PeerMessage>(&buf[..n], |m| messages.extend(m.ok()));
    }
    messages
}

fn plain_frame(request: &Request) -> Vec<u8> {
    let mut out = [0u8; MAX_FRAME];
    let len = encode_frame(request, &mut out).unwrap();
    out[..len].to_vec()
}

fn move_by(id: u32, axis: u8, steps: i32) -> Request {
    Request {
        id: RequestId(id),
        command: Command::MoveBy {
            deltas: delta(axis, steps).into_iter().collect(),
        },
    }
}

fn started(messages: &[PeerMessage]) -> bool {
    messages.iter().any(|m| {
        matches!(
            m,
            PeerMessage::Reply {
                reply: Reply::MoveStarted { .. },
                ..
            }
        )
    })
}

fn bad_seals(messages: &[PeerMessage]) -> usize {
    messages
        .iter()
        .filter(|m| matches!(m, PeerMessage::LinkError(e) if e.code == ErrorCode::BAD_SEAL))
        .count()
}

#[tokio::test]
async fn a_recorded_session_replayed_on_a_new_connection_moves_nothing() {
    let (peer, address) = peer(TimeMode::Instant).await;
    let proxy = Proxy::start(address).await;
    let victim = client(proxy.address, Some(KEY)).await.unwrap();
    let report = victim.move_by(&delta(0, 500)).await.unwrap();
    assert_eq!(report.positions[0], 500);
    let recorded = proxy.recorded.lock().unwrap().clone();
    drop(victim);
    let before = peer.shaft_positions();
    assert_eq!(before[0], 500);

    // The whole conversation, byte for byte, from another machine: handshake, the old
    // answer to an old challenge, the sealed move.
    let answers = raw_exchange(address, &recorded).await;
    assert!(!started(&answers), "{answers:?}");
    assert!(
        answers.iter().any(|m| matches!(m, PeerMessage::Reply { reply: Reply::Error(e), .. } if e.code == ErrorCode::AUTH_FAILED)),
        "the old answer does not fit the new challenge: {answers:?}"
    );
    assert!(
        bad_seals(&answers) >= 1,
        "the sealed move is refused: {answers:?}"
    );
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(peer.shaft_positions(), before, "nothing moved");

    // The sealed frames alone after a handshake of its own, as a stranger would try.
    let hello = plain_frame(&Request {
        id: RequestId(1),
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    });
    let sealed: Vec<u8> = recorded
        .split_inclusive(|&b| b == 0)
        .skip_while(|frame| frame.len() <= 1)
        .skip(3)
        .flatten()
        .copied()
        .collect();
    let answers = raw_exchange(address, &[hello, sealed].concat()).await;
    assert!(!started(&answers), "{answers:?}");
    assert!(bad_seals(&answers) >= 1, "{answers:?}");
    assert_eq!(peer.shaft_positions(), before, "nothing moved");
    let observer = client(address, None).await.unwrap();
    let security = observer.status().await.unwrap().security;
    assert!(security.rejected_frames >= 2, "{security:?}");
    assert_eq!(security.failed_authentications, 1);
}

#[tokio::test]
async fn frames_forged_into_a_live_session_are_dropped_and_the_session_goes_on() {
    let (peer, address) = peer(TimeMode::Instant).await;
    let proxy = Proxy::start(address).await;
    let victim = client(proxy.address, Some(KEY)).await.unwrap();
    proxy.record_from_now();
    victim.move_by(&delta(0, 100)).await.unwrap();
    let sent_move = proxy.frames().first().cloned().expect("the move's frame");
    let mut events = victim.events();
    let before = peer.shaft_positions();

    // A plain move, as anyone on the network could send; the session's own move frame again
    // (a replay inside the session); a move sealed under a made-up session key.
    proxy.inject(plain_frame(&move_by(0x7001, 0, 3000)));
    proxy.inject(sent_move);
    let mut forger = Sealer::new(
        session_key(&[0x42; 32], &[1; 16], &[2; 16]),
        Direction::ToController,
    );
    let mut out = [0u8; MAX_FRAME];
    let len = encode_sealed_frame(&move_by(0x7002, 1, -3000), &mut forger, &mut out).unwrap();
    proxy.inject(out[..len].to_vec());

    // Each is refused to the session (the refusal is sealed, so the victim sees it).
    let mut refusals = 0;
    let deadline = tokio::time::Instant::now() + Duration::from_secs(3);
    while refusals < 3 {
        let event = tokio::time::timeout_at(deadline, events.recv())
            .await
            .expect("three refusals")
            .unwrap();
        if let optalign::link::Event::LinkError(error) = event {
            assert_eq!(error.code, ErrorCode::BAD_SEAL, "{error}");
            refusals += 1;
        }
    }
    tokio::time::sleep(Duration::from_millis(100)).await;
    assert_eq!(peer.shaft_positions(), before, "nothing forged moved");

    // The session's own traffic goes on.
    let report = victim.move_by(&delta(0, 50)).await.unwrap();
    assert_eq!(report.positions[0], 150);
    let status = victim.status().await.unwrap();
    assert!(status.session.authenticated);
    assert_eq!(status.security.rejected_frames, 3);
}

#[tokio::test]
async fn a_wrong_key_is_refused_counted_and_backed_off_and_status_prints_it() {
    let (_peer, address) = peer(TimeMode::Scaled(1.0)).await;
    let error = client(address, Some("not-the-key")).await.err().unwrap();
    assert_eq!(error.code(), Some(ErrorCode::AUTH_FAILED), "{error}");

    // The next attempt, right key or not, waits out the backoff: 250 ms after one failure,
    // 500 ms after two in a row.
    let started = Instant::now();
    let error = client(address, Some("still-not-the-key"))
        .await
        .err()
        .unwrap();
    assert_eq!(error.code(), Some(ErrorCode::AUTH_FAILED), "{error}");
    let second = started.elapsed();
    let started = Instant::now();
    let honest = client(address, Some(KEY)).await.unwrap();
    let third = started.elapsed();
    assert!(second >= Duration::from_millis(200), "{second:?}");
    assert!(third >= Duration::from_millis(450), "{third:?}");
    assert!(honest.move_by(&delta(1, 10)).await.is_ok());

    let output = tokio::process::Command::new(BIN)
        .args(["status", "--controller", &format!("tcp://{address}")])
        .env_remove("OPTALIGN_KEY")
        .env("RUST_LOG", "error")
        .output()
        .await
        .unwrap();
    let text = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{text}");
    assert!(
        text.contains("network: 2 failed authentications and 0 rejected frames"),
        "{text}"
    );
}

#[tokio::test]
async fn strangers_make_room_for_a_client_with_the_key_and_idle_ones_are_closed() {
    let (peer, address) = peer(TimeMode::Instant).await;
    // An observer without the key and two connections that never say anything hold every
    // slot.
    let observer = client(address, None).await.unwrap();
    let opened = Instant::now();
    let mut squatters = Vec::new();
    for _ in 0..2 {
        squatters.push(TcpStream::connect(address).await.unwrap());
    }
    assert!(wait_for(|| peer.network_clients() == 3).await);

    // A client with the key is not kept out: a silent stranger makes room (once past the
    // short grace a newcomer gets to say something).
    let started = Instant::now();
    let controller = client(address, Some(KEY)).await.unwrap();
    assert!(
        started.elapsed() < Duration::from_secs(1),
        "{:?}",
        started.elapsed()
    );
    assert!(controller.move_by(&delta(0, 20)).await.is_ok());
    assert_eq!(peer.network_clients(), 3);

    // The other strangers are closed once idle for 5 s (the one evicted at once); until
    // then they hear the notifications every connection hears.
    for squatter in &mut squatters {
        let mut bytes = [0u8; 256];
        tokio::time::timeout(Duration::from_secs(8), async {
            while let Ok(1..) = squatter.read(&mut bytes).await {}
        })
        .await
        .expect("closed, not left open");
    }
    let waited = opened.elapsed();
    assert!(
        (Duration::from_millis(4500)..Duration::from_secs(8)).contains(&waited),
        "{waited:?}"
    );
    assert!(
        wait_for(|| peer.network_clients() == 1).await,
        "the idle observer was closed too, the key holder stays"
    );
    // The observer's client reconnects by itself at its next request.
    assert_eq!(observer.status().await.unwrap().axes[0].position, 20);
}

/// Polls `condition` for up to 2 s.
async fn wait_for(condition: impl Fn() -> bool) -> bool {
    for _ in 0..200 {
        if condition() {
            return true;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    condition()
}

#[tokio::test]
async fn a_hex_key_stands_for_its_passphrase_on_the_board_it_was_derived_for() {
    let (_peer, address) = peer(TimeMode::Instant).await;
    let board_id = client(address, None).await.unwrap().identity().board_id;
    let hex = optalign::link::key::to_hex(&optalign::link::key::stretch(KEY, board_id));
    let keyed = client(address, Some(&hex)).await.unwrap();
    assert!(keyed.move_by(&delta(0, 5)).await.is_ok());
    drop(keyed);

    // A peer provisioned with the hex key takes the passphrase's clients.
    let (_hex_peer, hex_address) = SimPeer::start_on_loopback(&PeerOptions {
        axes: 2,
        key: Some(hex),
        time: TimeMode::Instant,
        ..PeerOptions::default()
    })
    .await
    .unwrap();
    let by_passphrase = client(hex_address, Some(KEY)).await.unwrap();
    assert!(by_passphrase.move_by(&delta(1, 5)).await.is_ok());
}

/// A fake controller that answers the handshake and the challenge and accepts any answer,
/// unsealed, as a machine impersonating the controller would (it does not hold the key).
async fn impostor() -> SocketAddr {
    use optalign::link::framed::{FrameReader, write_frame};
    use optalign_protocol::{Capabilities, Identity};
    let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    tokio::spawn(async move {
        let (stream, _) = listener.accept().await.unwrap();
        let (read, mut write) = stream.into_split();
        let mut reader = FrameReader::<_, Request>::new(read);
        while let Ok(Some(Ok(request))) = reader.next().await {
            let reply = match request.command {
                Command::Hello { .. } => Reply::Hello(Identity {
                    protocol_version: PROTOCOL_VERSION,
                    firmware_version: "0".try_into().unwrap(),
                    board: "impostor".try_into().unwrap(),
                    board_id: 1,
                    axes: 2,
                    capabilities: Capabilities(0),
                    boot_nonce: 7,
                }),
                Command::AuthChallenge => Reply::Challenge { nonce: [0; 16] },
                _ => Reply::Ok,
            };
            let message = PeerMessage::Reply {
                id: request.id,
                reply,
            };
            if write_frame(&mut write, &message).await.is_err() {
                return;
            }
        }
    });
    address
}

#[tokio::test]
async fn a_controller_that_cannot_seal_its_answer_is_refused() {
    let address = impostor().await;
    let error = client(address, Some(KEY)).await.err().unwrap();
    assert!(
        matches!(error, optalign::link::ClientError::Impostor { .. }),
        "{error}"
    );
    assert!(
        error
            .to_string()
            .contains("without proving it holds the key"),
        "{error}"
    );
}
