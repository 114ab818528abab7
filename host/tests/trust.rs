//! The `optalign` command against a simulated peer on 127.0.0.1 when things go wrong: the
//! emergency latch.

use std::process::Output;

use optalign::peer::{PeerOptions, SimPeer, TimeMode};

const BIN: &str = env!("CARGO_BIN_EXE_optalign");
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

/// A simulated peer with the test key on a loopback port, moves completing at once.
async fn peer() -> (std::sync::Arc<SimPeer>, String) {
    let peer = SimPeer::start(&PeerOptions {
        axes: 2,
        key: Some(KEY.into()),
        time: TimeMode::Instant,
        ..PeerOptions::default()
    })
    .unwrap();
    let address = peer
        .listen_tcp("127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    (peer, format!("tcp://{address}"))
}

#[tokio::test]
async fn an_emergency_stop_refuses_moves_until_cleared() {
    let (peer, url) = peer().await;
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
