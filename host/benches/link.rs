//! Request round trip to the simulated peer over loopback TCP: criterion's timing of one
//! `Status` round trip, then a fixed run of requests that reports p50, p99 and requests per
//! second (criterion reports means and medians, not tail latency).

use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use optalign::link::{Client, ClientOptions, Endpoint};
use optalign::peer::{PeerOptions, SimPeer};

const TAIL_SAMPLES: usize = 20_000;

fn connect(runtime: &tokio::runtime::Runtime) -> (std::sync::Arc<SimPeer>, Client) {
    runtime.block_on(async {
        let (peer, address) = SimPeer::start_on_loopback(&PeerOptions::default())
            .await
            .expect("peer starts on loopback");
        let endpoint = Endpoint::Tcp {
            host: address.ip().to_string(),
            port: address.port(),
        };
        let client = Client::connect(endpoint, ClientOptions::default())
            .await
            .expect("client connects");
        (peer, client)
    })
}

fn percentile(sorted: &[Duration], fraction: f64) -> Duration {
    sorted[((sorted.len() - 1) as f64 * fraction).round() as usize]
}

fn bench_round_trip(c: &mut Criterion) {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let (_peer, client) = connect(&runtime);
    c.bench_function("status round trip over loopback TCP", |b| {
        b.to_async(&runtime)
            .iter(|| async { client.status().await.unwrap() })
    });

    let mut latencies = Vec::with_capacity(TAIL_SAMPLES);
    let started = Instant::now();
    runtime.block_on(async {
        for _ in 0..TAIL_SAMPLES {
            let sent = Instant::now();
            client.status().await.unwrap();
            latencies.push(sent.elapsed());
        }
    });
    let elapsed = started.elapsed();
    latencies.sort();
    println!(
        "status round trip, {TAIL_SAMPLES} sequential requests: p50 {:?}, p99 {:?}, max {:?}, {:.0} requests/s",
        percentile(&latencies, 0.50),
        percentile(&latencies, 0.99),
        latencies.last().unwrap(),
        TAIL_SAMPLES as f64 / elapsed.as_secs_f64()
    );
}

criterion_group!(benches, bench_round_trip);
criterion_main!(benches);
