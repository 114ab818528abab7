//! A controller that stops reading (its TCP window closes): the client's sends time out
//! with an error naming the controller, and nothing hangs.

use std::time::Duration;

use optalign::link::{Client, ClientError, ClientOptions, Endpoint, Unknown};
use optalign_protocol::{
    Capabilities, Command, FrameDecoder, Identity, MAX_FRAME, PROTOCOL_VERSION, PeerMessage, Reply,
    Request, encode_frame,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};
use tokio::task::JoinSet;

/// Answers the handshake on every connection, then never reads again (the connections
/// stay open, so their receive windows fill up and close).
async fn stalled_controller() -> std::net::SocketAddr {
    let socket = TcpSocket::new_v4().unwrap();
    socket.set_recv_buffer_size(4096).unwrap();
    socket.bind("127.0.0.1:0".parse().unwrap()).unwrap();
    let listener = socket.listen(16).unwrap();
    let address = listener.local_addr().unwrap();
    tokio::spawn(async move {
        let mut held = Vec::new();
        while let Ok((mut stream, _)) = listener.accept().await {
            answer_hello(&mut stream).await;
            held.push(stream);
        }
    });
    address
}

async fn answer_hello(stream: &mut TcpStream) {
    let mut decoder = FrameDecoder::new();
    let mut byte = [0u8; 1];
    let request = loop {
        if stream.read(&mut byte).await.unwrap_or(0) == 0 {
            return;
        }
        if let Some(Ok(request)) = decoder.push::<Request>(byte[0]) {
            break request;
        }
    };
    assert!(matches!(request.command, Command::Hello { .. }));
    let reply = PeerMessage::Reply {
        id: request.id,
        reply: Reply::Hello(Identity {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: "stalled".try_into().unwrap(),
            board: "test".try_into().unwrap(),
            board_id: 1,
            axes: 1,
            capabilities: Capabilities(0),
            boot_nonce: 7,
        }),
    };
    let mut frame = [0u8; MAX_FRAME];
    let len = encode_frame(&reply, &mut frame).unwrap();
    stream.write_all(&frame[..len]).await.unwrap();
}

#[tokio::test]
async fn a_controller_that_stops_reading_gives_a_send_timeout_naming_it() {
    let address = stalled_controller().await;
    let endpoint: Endpoint = format!("tcp://{address}").parse().unwrap();
    let client = std::sync::Arc::new(
        Client::connect(
            endpoint.clone(),
            ClientOptions {
                request_timeout: Duration::from_secs(2),
                send_timeout: Duration::from_millis(300),
                attempts: 1,
                ..ClientOptions::default()
            },
        )
        .await
        .unwrap(),
    );
    // Far more bytes than the socket buffers hold, none of them ever read.
    let wifi = Command::ProvisionWifi {
        ssid: "s".repeat(32).as_str().try_into().unwrap(),
        passphrase: "p".repeat(64).as_str().try_into().unwrap(),
    };
    // Batches of requests until the socket buffers are full and a send times out (or far
    // more bytes than any socket buffer holds were sent).
    let mut requests = JoinSet::new();
    let mut results = Vec::new();
    let send_timed_out = |results: &Vec<Result<Reply, ClientError>>| {
        results
            .iter()
            .any(|r| matches!(r, Err(ClientError::SendTimeout { .. })))
    };
    for _ in 0..40 {
        for _ in 0..10_000 {
            let (client, wifi) = (client.clone(), wifi.clone());
            requests.spawn(async move { client.request(wifi).await });
        }
        tokio::time::sleep(Duration::from_millis(400)).await;
        while let Some(done) = requests.try_join_next() {
            results.push(done.unwrap());
        }
        if send_timed_out(&results) {
            break;
        }
    }
    let rest = tokio::time::timeout(Duration::from_secs(60), requests.join_all())
        .await
        .expect("every request ends: nothing hangs");
    results.extend(rest);
    let send_timeouts: Vec<String> = results
        .iter()
        .filter_map(|result| match result {
            Err(error @ ClientError::SendTimeout { .. }) => Some(error.to_string()),
            _ => None,
        })
        .collect();
    assert!(
        !send_timeouts.is_empty(),
        "some send must have timed out: {:?}",
        results.iter().take(3).collect::<Vec<_>>()
    );
    let message = &send_timeouts[0];
    assert!(message.contains(&endpoint.to_string()), "{message}");
    assert!(message.contains("timed out after 300ms"), "{message}");
    // A request that went out whole and was never answered may have run: its outcome is
    // unknown; one that could not even be written timed out sending.
    assert!(
        results.iter().all(|result| matches!(
            result,
            Err(ClientError::SendTimeout { .. }
                | ClientError::Timeout { .. }
                | ClientError::OutcomeUnknown {
                    why: Unknown::Unanswered,
                    ..
                })
        )),
        "a controller that never answers gives timeouts and unknown outcomes only"
    );
}
