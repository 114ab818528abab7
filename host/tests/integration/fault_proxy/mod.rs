//! A fault-injecting TCP proxy for tests: it sits on 127.0.0.1 between a client and a
//! controller and, frame by frame (a frame ends at its `0x00` delimiter) and in both
//! directions, drops, duplicates, delays, splits or corrupts what passes, or resets the
//! connection. Every decision comes from a generator seeded from the proxy's seed, the
//! connection's number and the direction, so a seed replays the same faults on the same
//! traffic. Campaigns through it take their size from the environment ([`moves_from_env`]).

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use optalign_firmware::sim::SimRng;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::tcp::{OwnedReadHalf, OwnedWriteHalf};
use tokio::net::{TcpListener, TcpStream};
use tokio::task::{JoinHandle, JoinSet};

/// How often each fault strikes a frame, in frames per thousand (the rest pass intact).
#[derive(Clone, Copy, Debug)]
pub struct FaultRates {
    pub drop: u64,
    pub duplicate: u64,
    pub delay: u64,
    pub split: u64,
    pub corrupt: u64,
    pub reset: u64,
}

/// What the proxy did, counted over every connection and both directions.
#[derive(Debug, Default)]
pub struct Tally {
    pub frames: AtomicU64,
    pub dropped: AtomicU64,
    pub duplicated: AtomicU64,
    pub delayed: AtomicU64,
    pub split: AtomicU64,
    pub corrupted: AtomicU64,
    pub resets: AtomicU64,
}

impl Tally {
    /// Frames that met any fault (a reset counts once).
    pub fn faults(&self) -> u64 {
        [
            &self.dropped,
            &self.duplicated,
            &self.delayed,
            &self.split,
            &self.corrupted,
            &self.resets,
        ]
        .iter()
        .map(|count| count.load(Ordering::Relaxed))
        .sum()
    }
}

impl std::fmt::Display for Tally {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let get = |count: &AtomicU64| count.load(Ordering::Relaxed);
        write!(
            f,
            "{} frames: {} dropped, {} duplicated, {} delayed, {} split, {} corrupted, {} resets",
            get(&self.frames),
            get(&self.dropped),
            get(&self.duplicated),
            get(&self.delayed),
            get(&self.split),
            get(&self.corrupted),
            get(&self.resets),
        )
    }
}

/// A running proxy; dropping it stops it and closes every connection through it.
pub struct FaultProxy {
    address: SocketAddr,
    tally: Arc<Tally>,
    task: JoinHandle<()>,
}

impl FaultProxy {
    /// Listens on an ephemeral loopback port and relays each connection to `upstream`.
    pub async fn start(upstream: SocketAddr, seed: u64, rates: FaultRates) -> Self {
        let listener = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap();
        let tally = Arc::new(Tally::default());
        let shared = tally.clone();
        let task = tokio::spawn(async move {
            let mut connections = JoinSet::new();
            for number in 0u64.. {
                let Ok((client, _)) = listener.accept().await else {
                    return;
                };
                let seed = seed ^ number.wrapping_mul(0x9E37_79B9_7F4A_7C15);
                connections.spawn(relay(client, upstream, seed, rates, shared.clone()));
            }
        });
        Self {
            address,
            tally,
            task,
        }
    }

    pub fn address(&self) -> SocketAddr {
        self.address
    }

    pub fn tally(&self) -> &Tally {
        &self.tally
    }
}

impl Drop for FaultProxy {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Relays one connection until either side closes or a reset is injected; then both
/// sockets close.
async fn relay(
    client: TcpStream,
    upstream: SocketAddr,
    seed: u64,
    rates: FaultRates,
    tally: Arc<Tally>,
) {
    let Ok(server) = TcpStream::connect(upstream).await else {
        return;
    };
    let (client_read, client_write) = client.into_split();
    let (server_read, server_write) = server.into_split();
    tokio::select! {
        _ = pump(client_read, server_write, SimRng::new(seed), rates, &tally) => {}
        _ = pump(server_read, client_write, SimRng::new(!seed), rates, &tally) => {}
    }
}

/// Forwards whole frames from `from` to `to`, each meeting its fault; returns when the
/// stream ends or a reset is injected.
async fn pump(
    mut from: OwnedReadHalf,
    mut to: OwnedWriteHalf,
    mut rng: SimRng,
    rates: FaultRates,
    tally: &Tally,
) {
    let mut pending = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        let read = match from.read(&mut buf).await {
            Ok(0) | Err(_) => return,
            Ok(read) => read,
        };
        pending.extend_from_slice(&buf[..read]);
        while let Some(end) = pending.iter().position(|&b| b == 0) {
            let frame: Vec<u8> = pending.drain(..=end).collect();
            if forward(&frame, &mut to, &mut rng, rates, tally)
                .await
                .is_err()
            {
                return;
            }
        }
    }
}

/// The connection is to be reset (or the write failed).
struct Reset;

async fn write(to: &mut OwnedWriteHalf, bytes: &[u8]) -> Result<(), Reset> {
    to.write_all(bytes).await.map_err(|_| Reset)
}

async fn forward(
    frame: &[u8],
    to: &mut OwnedWriteHalf,
    rng: &mut SimRng,
    rates: FaultRates,
    tally: &Tally,
) -> Result<(), Reset> {
    tally.frames.fetch_add(1, Ordering::Relaxed);
    let count = |counter: &AtomicU64| counter.fetch_add(1, Ordering::Relaxed);
    let mut roll = rng.next_u64() % 1000;
    let detail = rng.next_u64();
    let mut strikes = |rate: u64| {
        let hit = roll < rate;
        roll = roll.saturating_sub(rate);
        hit
    };
    if strikes(rates.drop) {
        count(&tally.dropped);
        Ok(())
    } else if strikes(rates.duplicate) {
        count(&tally.duplicated);
        write(to, &[frame, frame].concat()).await
    } else if strikes(rates.delay) {
        count(&tally.delayed);
        tokio::time::sleep(Duration::from_millis(5 + detail % 60)).await;
        write(to, frame).await
    } else if strikes(rates.split) && frame.len() > 1 {
        count(&tally.split);
        let cut = 1 + (detail as usize) % (frame.len() - 1);
        write(to, &frame[..cut]).await?;
        to.flush().await.map_err(|_| Reset)?;
        tokio::time::sleep(Duration::from_millis(2)).await;
        write(to, &frame[cut..]).await
    } else if strikes(rates.corrupt) {
        count(&tally.corrupted);
        let mut bytes = frame.to_vec();
        let at = (detail as usize) % bytes.len();
        bytes[at] ^= 1 << ((detail >> 32) % 8);
        write(to, &bytes).await
    } else if strikes(rates.reset) {
        count(&tally.resets);
        Err(Reset)
    } else {
        write(to, frame).await
    }
}

/// The number of moves a campaign makes: the whole number in environment variable `name`,
/// else `default`.
pub fn moves_from_env(name: &str, default: usize) -> usize {
    match std::env::var(name) {
        Ok(text) => text
            .parse()
            .unwrap_or_else(|_| panic!("{name} must be a whole number, got {text:?}")),
        Err(_) => default,
    }
}
