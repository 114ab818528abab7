//! The kill campaign: random moves from a controlling client through the fault-injecting
//! proxy (see `fault_proxy`), while two observers poll `Status`, a third sends `Stop` (which
//! a client without the key is refused) and now and then `EmergencyStop`, an operator on
//! the serial link stops moves, and the controller loses its power at random instants,
//! sometimes in the middle of a flash write, and starts again on the same bench (the
//! mounts keep their shafts, the flash what was written; see `optalign::peer::Bench`).
//!
//! Checked against the bench's truth, not the link: no request id is started twice (the
//! bench logs every move the controller starts, over all its start-ups); every `Status`
//! the controller gives shows each axis at its true shaft position or flagged
//! `POSITION_LOST` (the bench audits each one as it is made); a move the host reports
//! completed (or stopped) ended so on the controller, at the positions reported; and
//! every call returns within a bound.
//!
//! 200 moves by default (about 40 s); `OPTALIGN_CAMPAIGN_MOVES=N` runs N.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::fault_proxy::{FaultProxy, FaultRates};
use optalign::link::{Client, ClientError, ClientOptions};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_firmware::sim::SimRng;
use optalign_protocol::{
    AxisConfig, AxisValue, BacklashMode, Command, ErrorCode, Faults, MoveOutcome, RequestId,
};

const KEY: &str = "kill-campaign-key";
const AXES: u8 = 3;
/// The longest any one call may take before the campaign calls it a hang.
const BOUND: Duration = Duration::from_secs(30);

const RATES: FaultRates = FaultRates {
    drop: 20,
    duplicate: 20,
    delay: 20,
    split: 20,
    corrupt: 20,
    reset: 5,
};

fn peer_options() -> PeerOptions {
    PeerOptions {
        axes: AXES,
        key: Some(KEY.into()),
        time: TimeMode::Scaled(2.0),
        max_clients: 8,
        ..PeerOptions::default()
    }
}

async fn bounded<T>(what: &str, call: impl Future<Output = T>) -> T {
    tokio::time::timeout(BOUND, call)
        .await
        .unwrap_or_else(|_| panic!("{what} hung for {BOUND:?}"))
}

/// The controller now running, and what became of the ones before it.
struct Controller {
    options: PeerOptions,
    address: SocketAddr,
    peer: Mutex<Arc<SimPeer>>,
    kills: AtomicU64,
    torn_writes: AtomicU64,
}

impl Controller {
    async fn start() -> Arc<Self> {
        let options = peer_options();
        let (peer, address) = SimPeer::start_on_loopback(&options).await.unwrap();
        {
            let core = peer.core();
            let mut bench = core.bench().lock().unwrap();
            bench.audit_positions();
            bench.keep_log();
        }
        let controller = Arc::new(Self {
            options,
            address,
            peer: Mutex::new(peer),
            kills: AtomicU64::default(),
            torn_writes: AtomicU64::default(),
        });
        controller.configure();
        controller
    }

    fn peer(&self) -> Arc<SimPeer> {
        self.peer.lock().unwrap().clone()
    }

    /// On the serial link (physical access): fast axes without backlash compensation, so
    /// moves are short and every shaft follows its motor exactly.
    fn configure(&self) {
        let fast = |config| AxisConfig {
            max_speed: 20_000,
            acceleration: 400_000,
            backlash_mode: BacklashMode::Off,
            ..config
        };
        self.peer()
            .reconfigure_over_serial(fast)
            .expect("fast axes");
    }

    /// Stops the move in progress from the serial link.
    fn stop_on_serial(&self) {
        self.peer().serial_request(Command::Stop);
    }

    /// Cuts the power now, or in the next flash write (`tear`), and starts the controller
    /// again on what the cut left, on the same address.
    async fn power_cut(&self, tear: Option<(u32, usize)>, off_for: Duration) {
        let peer = self.peer();
        if let Some((writes, bytes)) = tear {
            peer.core()
                .bench()
                .lock()
                .unwrap()
                .cut_power_in_write(writes, bytes);
            for _ in 0..100 {
                if peer.core().is_off() {
                    self.torn_writes.fetch_add(1, Ordering::Relaxed);
                    break;
                }
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        }
        let bench = peer.kill();
        self.kills.fetch_add(1, Ordering::Relaxed);
        tokio::time::sleep(off_for).await;
        let next = SimPeer::start_on_bench(&self.options, bench).unwrap();
        let mut bound = None;
        for _ in 0..200 {
            match next.listen_tcp(self.address).await {
                Ok(address) => {
                    bound = Some(address);
                    break;
                }
                // The old listener closes as its task is aborted, a moment later.
                Err(_) => tokio::time::sleep(Duration::from_millis(5)).await,
            }
        }
        assert_eq!(bound, Some(self.address), "the controller listens again");
        *self.peer.lock().unwrap() = next;
        self.configure();
    }
}

/// Cuts the power at random instants until `done`; a third of the cuts land in a flash
/// write, at a random byte.
async fn killer(controller: Arc<Controller>, seed: u64, done: Arc<AtomicBool>) {
    let mut rng = SimRng::new(seed);
    while !done.load(Ordering::Relaxed) {
        tokio::time::sleep(Duration::from_millis(100 + rng.next_u64() % 900)).await;
        if done.load(Ordering::Relaxed) {
            return;
        }
        let tear = rng.next_u64().is_multiple_of(3).then(|| {
            let writes = (rng.next_u64() % 2) as u32;
            // A record is a few hundred bytes: most cuts land inside it.
            (writes, (rng.next_u64() % 256) as usize)
        });
        let off_for = Duration::from_millis(rng.next_u64() % 60);
        controller.power_cut(tear, off_for).await;
    }
}

#[derive(Debug, Default)]
struct Observed {
    statuses: AtomicU64,
    stops_refused: AtomicU64,
    emergency_stops: AtomicU64,
    serial_stops: AtomicU64,
}

fn client_options(key: bool) -> ClientOptions {
    ClientOptions {
        key: key.then(|| optalign::link::AccessKey::passphrase(KEY)),
        request_timeout: Duration::from_millis(250),
        attempts: 6,
        connect_timeout: Duration::from_secs(1),
        send_timeout: Duration::from_secs(1),
        deadline: Duration::from_secs(10),
    }
}

async fn connect(url: &str, key: bool) -> Client {
    for _ in 0..100 {
        if let Ok(client) = Client::connect(url.parse().unwrap(), client_options(key)).await {
            return client;
        }
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    panic!("cannot connect to {url}");
}

/// Polls `Status` until `done` (the bench audits every answer).
async fn poller(url: String, observed: Arc<Observed>, done: Arc<AtomicBool>) {
    let client = connect(&url, false).await;
    while !done.load(Ordering::Relaxed) {
        if bounded("an observer's Status", client.status())
            .await
            .is_ok()
        {
            observed.statuses.fetch_add(1, Ordering::Relaxed);
        }
        tokio::time::sleep(Duration::from_millis(15)).await;
    }
}

/// Sends `Stop` (refused: it has no key) and, rarely, `EmergencyStop`; now and then
/// an operator on the serial link stops the move in progress.
async fn stopper(
    url: String,
    controller: Arc<Controller>,
    seed: u64,
    observed: Arc<Observed>,
    done: Arc<AtomicBool>,
) {
    let client = connect(&url, false).await;
    let mut rng = SimRng::new(seed);
    while !done.load(Ordering::Relaxed) {
        tokio::time::sleep(Duration::from_millis(50 + rng.next_u64() % 400)).await;
        match rng.next_u64() % 20 {
            0 => {
                if bounded(
                    "an emergency stop",
                    client.command_ok(Command::EmergencyStop),
                )
                .await
                .is_ok()
                {
                    observed.emergency_stops.fetch_add(1, Ordering::Relaxed);
                }
            }
            1..=4 => {
                controller.stop_on_serial();
                observed.serial_stops.fetch_add(1, Ordering::Relaxed);
            }
            _ => {
                // Without the key, a Stop over the network is refused (`unauthorized`).
                if let Err(error) = bounded("a Stop", client.command_ok(Command::Stop)).await
                    && error.code().is_some()
                {
                    observed.stops_refused.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    }
}

/// A random move: `MoveBy` of up to ±800 steps or `MoveTo` within ±3000, on one to three
/// axes.
fn random_move(rng: &mut SimRng) -> Command {
    let relative = !rng.next_u64().is_multiple_of(3);
    let mut values = heapless::Vec::new();
    for axis in 0..AXES {
        if rng.next_u64().is_multiple_of(3) && !(axis == AXES - 1 && values.is_empty()) {
            continue;
        }
        let steps = if relative {
            (rng.next_u64() % 1601) as i32 - 800
        } else {
            (rng.next_u64() % 6001) as i32 - 3000
        };
        values.push(AxisValue { axis, steps }).unwrap();
    }
    if relative {
        Command::MoveBy { deltas: values }
    } else {
        Command::MoveTo { targets: values }
    }
}

#[derive(Debug, Default)]
struct Figures {
    moves: usize,
    completed: usize,
    stopped: usize,
    unknown: usize,
    gave_up: usize,
    refused_busy: usize,
    refused_lost: usize,
    refused_emergency: usize,
    re_zeroed: usize,
}

/// Declares every axis flagged `POSITION_LOST` at its true shaft position (what homing
/// would find), as an operator does after a power cut.
async fn re_zero(client: &Client, controller: &Controller, figures: &mut Figures) {
    let Ok(status) = bounded("Status before re-zeroing", client.status()).await else {
        return;
    };
    let shafts = controller.peer().shaft_positions();
    for (axis, state) in (0u8..).zip(&status.axes) {
        if state.faults.has(Faults::POSITION_LOST) {
            let command = Command::SetPosition {
                axis,
                position: shafts[usize::from(axis)],
            };
            if bounded("SetPosition", client.command_ok(command))
                .await
                .is_ok()
            {
                figures.re_zeroed += 1;
            }
        }
    }
}

/// Checks one move the client reports ended against the bench's log.
fn check_report(
    controller: &Controller,
    id: RequestId,
    outcome: MoveOutcome,
    positions: &[i32],
    command: &Command,
) {
    let peer = controller.peer();
    let core = peer.core();
    let bench = core.bench().lock().unwrap();
    let log = bench.log().expect("the log is kept");
    assert_eq!(log.starts(id.0), 1, "{id:?} {command:?} started once");
    let finish = log.finish(id.0);
    assert_eq!(
        finish,
        Some(&(outcome, positions.to_vec())),
        "the host reports {id:?} {command:?} ended {outcome:?} at {positions:?}; the \
         controller logged {finish:?}"
    );
}

async fn campaign(seed: u64, moves: usize) -> (Figures, String) {
    let controller = Controller::start().await;
    let proxy = FaultProxy::start(controller.address, seed, RATES).await;
    let url = format!("tcp://{}", proxy.address());
    let done = Arc::new(AtomicBool::new(false));
    let observed = Arc::new(Observed::default());
    let mut helpers = tokio::task::JoinSet::new();
    for _ in 0..2 {
        helpers.spawn(poller(url.clone(), observed.clone(), done.clone()));
    }
    helpers.spawn(stopper(
        url.clone(),
        controller.clone(),
        seed ^ 0x5709,
        observed.clone(),
        done.clone(),
    ));
    helpers.spawn(killer(controller.clone(), seed ^ 0xdead, done.clone()));

    let client = connect(&url, true).await;
    let mut rng = SimRng::new(seed);
    let mut figures = Figures::default();
    for number in 0..moves {
        let command = random_move(&mut rng);
        let id = client.next_request_id();
        figures.moves += 1;
        let result = bounded("a move", client.run_move_with_id(id, command.clone())).await;
        match result {
            Ok(report) => {
                check_report(&controller, id, report.outcome, &report.positions, &command);
                match report.outcome {
                    MoveOutcome::Completed => figures.completed += 1,
                    _ => figures.stopped += 1,
                }
            }
            Err(ClientError::OutcomeUnknown { .. }) => figures.unknown += 1,
            Err(
                error @ (ClientError::Timeout { .. }
                | ClientError::MoveTimeout { .. }
                | ClientError::Io { .. }
                | ClientError::Connect { .. }
                | ClientError::SendTimeout { .. }),
            ) => {
                eprintln!("seed {seed:#x}, move {number}: gave up: {error}");
                figures.gave_up += 1
            }
            Err(error) if error.code() == Some(ErrorCode::BUSY) => figures.refused_busy += 1,
            Err(error) if error.code() == Some(ErrorCode::AXIS_FAULT) => {
                figures.refused_lost += 1;
                re_zero(&client, &controller, &mut figures).await;
            }
            Err(error) if error.code() == Some(ErrorCode::EMERGENCY_STOPPED) => {
                figures.refused_emergency += 1;
                let _ = bounded("ClearEmergency", client.command_ok(Command::ClearEmergency)).await;
            }
            Err(error) => panic!("seed {seed:#x}, move {number}: {command:?} failed: {error}"),
        }
        if number % 500 == 499 {
            eprintln!("seed {seed:#x}: {} moves, {figures:?}", number + 1);
        }
    }
    done.store(true, Ordering::Relaxed);
    while let Some(joined) = bounded("the helpers' end", helpers.join_next()).await {
        joined.unwrap();
    }

    let peer = controller.peer();
    let core = peer.core();
    let bench = core.bench().lock().unwrap();
    let log = bench.log().expect("the log is kept");
    let twice = log.started_twice();
    assert!(twice.is_empty(), "seed {seed:#x}: started twice: {twice:?}");
    let audit = bench.audit().expect("the audit runs");
    assert!(
        audit.unflagged.is_empty(),
        "seed {seed:#x}: unflagged lost positions: {:?}",
        audit.unflagged
    );
    let kills = controller.kills.load(Ordering::Relaxed);
    let torn = controller.torn_writes.load(Ordering::Relaxed);
    let summary = format!(
        "seed {seed:#x}: {figures:?}; moves started {}, statuses audited {}, kills {kills} \
         ({torn} in a flash write), stops refused {}, serial stops {}, emergency stops {}; \
         proxy: {}",
        log.total_starts(),
        audit.checked,
        observed.stops_refused.load(Ordering::Relaxed),
        observed.serial_stops.load(Ordering::Relaxed),
        observed.emergency_stops.load(Ordering::Relaxed),
        proxy.tally(),
    );
    assert!(kills > 0, "{summary}: the controller was never killed");
    assert!(
        proxy.tally().faults() > 0,
        "{summary}: no fault was injected"
    );
    assert!(audit.checked > 0, "{summary}: no status was audited");
    assert!(
        figures.completed > moves / 3,
        "{summary}: too few moves completed to mean anything"
    );
    (figures, summary)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn killed_at_random_no_move_runs_twice_and_no_lost_position_goes_unflagged() {
    let moves = crate::fault_proxy::moves_from_env("OPTALIGN_CAMPAIGN_MOVES", 200);
    let (_, summary) = campaign(0xC0FFEE, moves).await;
    println!("{summary}");
}
