//! The soak: eight network clients on one simulated controller for minutes of simulated
//! time (the peer's clock runs `SCALE` times as fast as the wall clock): one controlling
//! client moves without pause, five poll `Status`, two send `Stop` (refused: they hold no
//! key, so control stays with the mover). The observers' round trips are timed on the
//! wall clock, and the process's resident memory (`VmRSS`, peer and clients together) is
//! sampled every second of wall time.
//!
//! Asserted: every move completes, no request fails, p99 stays under `P99_BOUND`, and the
//! memory after the first quarter grows by less than `GROWTH_BOUND_KIB`.
//! One simulated minute by default (about 5 s); `OPTALIGN_SOAK_MINUTES=N` runs N.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use optalign::link::{Client, ClientOptions};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_firmware::sim::SimRng;
use optalign_protocol::{AxisConfig, AxisValue, Command, ErrorCode, MoveOutcome};

const KEY: &str = "soak-key";
const AXES: u8 = 3;
/// Simulated seconds per wall second.
const SCALE: f64 = 15.0;
const POLLERS: usize = 5;
const STOPPERS: usize = 2;
const P99_BOUND: Duration = Duration::from_millis(250);
const GROWTH_BOUND_KIB: u64 = 16 * 1024;

fn sim_minutes() -> f64 {
    match std::env::var("OPTALIGN_SOAK_MINUTES") {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("OPTALIGN_SOAK_MINUTES must be a number, got {text:?}")),
        Err(_) => 1.0,
    }
}

/// Resident memory of this process, KiB (`VmRSS` in `/proc/self/status`).
fn resident_kib() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").expect("/proc/self/status");
    status
        .lines()
        .find_map(|line| line.strip_prefix("VmRSS:"))
        .and_then(|rest| rest.trim().trim_end_matches("kB").trim().parse().ok())
        .expect("a VmRSS line")
}

fn options(key: bool) -> ClientOptions {
    ClientOptions {
        key: key.then(|| optalign::link::AccessKey::passphrase(KEY)),
        request_timeout: Duration::from_secs(2),
        attempts: 2,
        ..ClientOptions::default()
    }
}

/// Round trips timed by the observers, in a histogram of fixed size (10 µs buckets up to
/// one second, then one for everything slower), so the measurement does not grow the
/// memory it watches.
struct Latencies(Mutex<Vec<u64>>);

const BUCKET_US: u64 = 10;
const BUCKETS: usize = 100_000;

impl Latencies {
    fn new() -> Self {
        Self(Mutex::new(vec![0; BUCKETS + 1]))
    }

    async fn time<T>(&self, call: impl Future<Output = T>) -> T {
        let start = Instant::now();
        let result = call.await;
        let bucket = (start.elapsed().as_micros() as u64 / BUCKET_US).min(BUCKETS as u64);
        self.0.lock().unwrap()[bucket as usize] += 1;
        result
    }

    fn count(&self) -> u64 {
        self.0.lock().unwrap().iter().sum()
    }

    /// The upper edge of the bucket holding the `p` quantile.
    fn percentile(&self, p: f64) -> Duration {
        let counts = self.0.lock().unwrap();
        let wanted = (counts.iter().sum::<u64>() as f64 * p).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (bucket, &count) in counts.iter().enumerate() {
            seen += count;
            if seen >= wanted {
                return Duration::from_micros((bucket as u64 + 1) * BUCKET_US);
            }
        }
        Duration::MAX
    }
}

async fn poller(client: Client, latencies: Arc<Latencies>, done: Arc<AtomicBool>) -> u64 {
    let mut served = 0;
    while !done.load(Ordering::Relaxed) {
        let status = latencies.time(client.status()).await;
        status.expect("Status under load");
        served += 1;
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    served
}

async fn stopper(client: Client, latencies: Arc<Latencies>, done: Arc<AtomicBool>) -> u64 {
    let mut refused = 0;
    while !done.load(Ordering::Relaxed) {
        let error = latencies
            .time(client.command_ok(Command::Stop))
            .await
            .expect_err("a Stop without the key is refused");
        assert_eq!(error.code(), Some(ErrorCode::UNAUTHORIZED), "{error}");
        refused += 1;
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    refused
}

async fn fast_axes(peer: &SimPeer) {
    let fast = |config| AxisConfig {
        max_speed: 5_000,
        acceleration: 50_000,
        ..config
    };
    peer.reconfigure_over_serial(fast).expect("fast axes");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eight_clients_for_minutes_keep_latency_low_and_memory_flat() {
    let minutes = sim_minutes();
    let wall = Duration::from_secs_f64(minutes * 60.0 / SCALE);
    let (peer, address) = SimPeer::start_on_loopback(&PeerOptions {
        axes: AXES,
        key: Some(KEY.into()),
        time: TimeMode::Scaled(SCALE),
        max_clients: 1 + POLLERS + STOPPERS + 1,
        ..PeerOptions::default()
    })
    .await
    .unwrap();
    fast_axes(&peer).await;
    let url = format!("tcp://{address}");
    let connect = |key| {
        let url = url.clone();
        async move {
            Client::connect(url.parse().unwrap(), options(key))
                .await
                .unwrap()
        }
    };
    let latencies = Arc::new(Latencies::new());
    let done = Arc::new(AtomicBool::new(false));
    let mover = connect(true).await;
    let mut pollers = tokio::task::JoinSet::new();
    for _ in 0..POLLERS {
        pollers.spawn(poller(
            connect(false).await,
            latencies.clone(),
            done.clone(),
        ));
    }
    let mut stoppers = tokio::task::JoinSet::new();
    for _ in 0..STOPPERS {
        stoppers.spawn(stopper(
            connect(false).await,
            latencies.clone(),
            done.clone(),
        ));
    }
    assert_eq!(peer.network_clients(), 1 + POLLERS + STOPPERS);

    let memory = Arc::new(Mutex::new(Vec::new()));
    let sampler = {
        let (memory, done) = (memory.clone(), done.clone());
        tokio::spawn(async move {
            let start = Instant::now();
            while !done.load(Ordering::Relaxed) {
                memory
                    .lock()
                    .unwrap()
                    .push((start.elapsed().as_secs_f64(), resident_kib()));
                tokio::time::sleep(Duration::from_secs(1)).await;
            }
        })
    };

    let started = Instant::now();
    let mut rng = SimRng::new(0x50A4);
    let mut moves = 0u64;
    while started.elapsed() < wall {
        let axis = (rng.next_u64() % u64::from(AXES)) as u8;
        let steps = (rng.next_u64() % 1001) as i32 - 500;
        let report = mover
            .move_by(&[AxisValue { axis, steps }])
            .await
            .expect("a move under load");
        assert_eq!(report.outcome, MoveOutcome::Completed);
        moves += 1;
    }
    done.store(true, Ordering::Relaxed);
    let mut statuses = 0;
    while let Some(served) = pollers.join_next().await {
        statuses += served.unwrap();
    }
    let mut stops = 0;
    while let Some(refused) = stoppers.join_next().await {
        stops += refused.unwrap();
    }
    sampler.await.unwrap();

    let p50 = latencies.percentile(0.50);
    let p99 = latencies.percentile(0.99);
    let max = latencies.percentile(1.0);
    let samples = memory.lock().unwrap().clone();
    let settled = samples[samples.len() / 4].1;
    let last = samples.last().unwrap().1;
    let peak = samples.iter().map(|&(_, kib)| kib).max().unwrap();
    let trend: Vec<String> = samples
        .iter()
        .step_by((samples.len() / 8).max(1))
        .map(|(t, kib)| format!("{t:.0}s {:.1} MiB", *kib as f64 / 1024.0))
        .collect();
    println!(
        "{minutes} simulated minutes in {:.1} s: {moves} moves, {statuses} statuses, {stops} \
         stops refused; {} round trips: p50 {p50:?}, p99 {p99:?}, max {max:?}; resident \
         memory {} -> {} KiB (peak {peak}); trend: {}",
        started.elapsed().as_secs_f64(),
        latencies.count(),
        settled,
        last,
        trend.join(", ")
    );
    assert!(moves > 0 && statuses > 0 && stops > 0);
    assert!(p99 < P99_BOUND, "p99 {p99:?} is above {P99_BOUND:?}");
    assert!(
        last.saturating_sub(settled) < GROWTH_BOUND_KIB,
        "memory grew from {settled} KiB to {last} KiB"
    );
}
