//! The simulated peer's bounds, on 127.0.0.1: a connection cap whose newcomers evict
//! strangers, past key holders only stop, and a client that never reads its replies is
//! throttled instead of buffered without end, and closed.

use std::sync::Arc;
use std::time::Duration;

use optalign::link::{AccessKey, Client, ClientError, ClientOptions, Endpoint};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_firmware::admission::{AUTH_GRACE_US, SILENT_GRACE_US};
use optalign_protocol::{
    Command, ErrorCode, MAX_FRAME, PROTOCOL_VERSION, Request, RequestId, encode_frame,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};

const KEY: &str = "limits-test-key";

async fn peer(max_clients: usize) -> (Arc<SimPeer>, Endpoint) {
    let (peer, address) = SimPeer::start_on_loopback(&PeerOptions {
        axes: 2,
        key: Some(KEY.into()),
        time: TimeMode::Instant,
        max_clients,
        ..PeerOptions::default()
    })
    .await
    .unwrap();
    (peer, format!("tcp://{address}").parse().unwrap())
}

async fn connect(endpoint: &Endpoint, key: bool) -> Result<Client, ClientError> {
    Client::connect(
        endpoint.clone(),
        ClientOptions {
            key: key.then(|| AccessKey::passphrase(KEY)),
            ..ClientOptions::default()
        },
    )
    .await
}

/// Waits until the peer counts `open` network connections.
async fn until_open(peer: &SimPeer, open: usize) {
    for _ in 0..200 {
        if peer.network_clients() == open {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!(
        "{} connections open, expected {open}",
        peer.network_clients()
    );
}

/// Reads until `stream` is closed by the peer; false if it stays open `within`.
async fn closed_within(stream: &mut TcpStream, within: Duration) -> bool {
    let mut byte = [0u8; 64];
    tokio::time::timeout(within, async {
        while let Ok(1..) = stream.read(&mut byte).await {}
    })
    .await
    .is_ok()
}

/// Replaces the rule this file encoded before (the last free slot kept for a client with
/// the key, and a full peer refusing newcomers): strangers holding every slot let
/// four silent clients lock everyone out (issue 31), so a newcomer now evicts them.
#[tokio::test]
async fn a_full_peer_evicts_strangers_for_newcomers_and_past_key_holders_only_stops() {
    let (peer, endpoint) = peer(2).await;
    let Endpoint::Tcp { host, port } = &endpoint else {
        unreachable!()
    };
    let address = format!("{host}:{port}");
    // Two strangers hold both slots: an observer without the key, and a silent one.
    let observer = connect(&endpoint, false).await.unwrap();
    assert!(observer.status().await.is_ok());
    let mut silent = TcpStream::connect(&address).await.unwrap();
    until_open(&peer, 2).await;
    tokio::time::sleep(Duration::from_micros(SILENT_GRACE_US + 50_000)).await;

    // A client with the key gets in: the silent stranger goes first.
    let controller = connect(&endpoint, true).await.unwrap();
    assert!(closed_within(&mut silent, Duration::from_secs(1)).await);
    assert!(controller.status().await.is_ok());
    assert!(observer.status().await.is_ok(), "the observer still served");

    // The observer spoke, so it has longer to authenticate; then it goes too.
    tokio::time::sleep(Duration::from_micros(AUTH_GRACE_US)).await;
    let second = connect(&endpoint, true).await.unwrap();
    assert!(second.status().await.is_ok());
    until_open(&peer, 2).await;

    // Every slot held by a key holder: a newcomer may only shake hands and stop.
    let quick = ClientOptions {
        key: Some(AccessKey::passphrase(KEY)),
        deadline: Duration::from_millis(600),
        ..ClientOptions::default()
    };
    let error = Client::connect(endpoint.clone(), quick)
        .await
        .err()
        .expect("no slot for a third key holder");
    assert!(
        matches!(error, ClientError::Deadline { .. }),
        "tried until its deadline: {error}"
    );
    let stopper = connect(&endpoint, false).await.unwrap();
    let error = stopper.status().await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::BUSY), "{error}");
    assert!(
        error.to_string().contains("only Hello and EmergencyStop"),
        "{error}"
    );
    let stopper = connect(&endpoint, false).await.unwrap();
    stopper.command_ok(Command::EmergencyStop).await.unwrap();
    assert!(
        controller.status().await.unwrap().emergency_stopped,
        "the stop-only connection stopped the motors"
    );

    // A key holder leaving frees its slot.
    drop(second);
    until_open(&peer, 2).await;
    let again = connect(&endpoint, true).await.unwrap();
    assert!(again.status().await.is_ok());
}

#[tokio::test]
async fn a_client_that_never_reads_its_replies_is_throttled_not_buffered() {
    let (peer, endpoint) = peer(4).await;
    let Endpoint::Tcp { host, port } = &endpoint else {
        unreachable!()
    };
    // Small socket buffers on the client, so the backlog shows in the peer.
    let socket = TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    socket.set_send_buffer_size(4096).unwrap();
    let mut stream = socket
        .connect(format!("{host}:{port}").parse().unwrap())
        .await
        .unwrap();
    let mut frame = [0u8; MAX_FRAME];
    let mut chunk = Vec::new();
    let hello = Request {
        id: RequestId(1),
        command: Command::Hello {
            protocol_version: PROTOCOL_VERSION,
        },
    };
    let len = encode_frame(&hello, &mut frame).unwrap();
    stream.write_all(&frame[..len]).await.unwrap();
    for id in 2..1_002 {
        let status = Request {
            id: RequestId(id),
            command: Command::Status,
        };
        let len = encode_frame(&status, &mut frame).unwrap();
        chunk.extend_from_slice(&frame[..len]);
    }

    // Status requests (each answered by a much longer reply), never reading a reply: the
    // peer must stop reading them long before 64 MiB of requests.
    let mut sent = 0usize;
    let blocked = loop {
        match tokio::time::timeout(Duration::from_millis(500), stream.write_all(&chunk)).await {
            Ok(written) => {
                written.unwrap();
                sent += chunk.len();
                if sent > 64 << 20 {
                    break false;
                }
            }
            Err(_) => break true,
        }
    };
    assert!(blocked, "the peer kept reading {sent} bytes of requests");

    // Meanwhile everyone else is served.
    let other = connect(&endpoint, false).await.unwrap();
    let status = tokio::time::timeout(Duration::from_secs(5), other.status())
        .await
        .expect("served while another client is stuck");
    assert!(status.is_ok());
    drop(stream);
    drop(peer);
}
