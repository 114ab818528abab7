//! The simulated peer's bounds, on 127.0.0.1: a connection cap that refuses clearly and
//! keeps the last slot for a client that authenticates, and a client that never reads its
//! replies is throttled instead of buffered without end.

use std::sync::Arc;
use std::time::Duration;

use optalign::link::{AccessKey, Client, ClientError, ClientOptions, Endpoint};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_protocol::{
    Command, ErrorCode, MAX_FRAME, PROTOCOL_VERSION, Request, RequestId, encode_frame,
};
use tokio::io::AsyncWriteExt;
use tokio::net::TcpSocket;

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

#[tokio::test]
async fn a_full_peer_refuses_clearly_and_keeps_the_last_slot_for_a_controller() {
    let (peer, endpoint) = peer(3).await;
    let controller = connect(&endpoint, true).await.unwrap();
    let observer = connect(&endpoint, false).await.unwrap();
    assert!(observer.status().await.is_ok());
    until_open(&peer, 2).await;

    // The last slot: an observer without the key may shake hands, but nothing more.
    let squatter = connect(&endpoint, false).await.unwrap();
    let error = squatter.status().await.unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::BUSY), "{error}");
    assert!(
        error
            .to_string()
            .contains("kept for a client that authenticates"),
        "{error}"
    );
    until_open(&peer, 2).await;

    // A client with the key takes it and is served.
    let second = connect(&endpoint, true).await.unwrap();
    assert!(second.status().await.is_ok());
    until_open(&peer, 3).await;

    // Full: refused with a reason, at once.
    let refused = tokio::time::timeout(Duration::from_secs(5), connect(&endpoint, true))
        .await
        .expect("a refusal, not a hang");
    let error = refused.err().expect("no slot is free");
    assert_eq!(error.code(), Some(ErrorCode::BUSY), "{error}");
    assert!(
        error
            .to_string()
            .contains("all 3 network client slots are taken"),
        "{error}"
    );

    // The others are still served, and a closed connection frees its slot.
    assert!(controller.status().await.is_ok());
    drop(second);
    until_open(&peer, 2).await;
    let again = connect(&endpoint, true).await.unwrap();
    assert!(again.status().await.is_ok());
    drop(observer);
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
