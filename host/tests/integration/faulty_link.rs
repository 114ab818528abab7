//! Moves through a faulty link: a client drives a simulated peer through a proxy on
//! 127.0.0.1 that drops, duplicates, delays, splits and corrupts frames in both directions
//! and resets connections (see `fault_proxy`). After every move the test reads the peer's
//! true state directly, not through the link, and checks that every move the client
//! reports completed happened exactly once, that no move ran twice (a direct observer
//! counts the peer's `MoveFinished` per request id), that a move whose outcome the client
//! could not learn is reconciled honestly through `MoveResult`, and that the client's idea
//! of every axis position equals the controller's.
//!
//! 210 moves over three seeds by default; `OPTALIGN_FAULT_MOVES=N` runs N moves per seed.

use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::fault_proxy::{FaultProxy, FaultRates};
use optalign::link::{Client, ClientError, ClientOptions, Event};
use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use optalign_firmware::Session;
use optalign_firmware::sim::SimRng;
use optalign_protocol::{
    AxisConfig, AxisValue, Command, ErrorCode, MoveOutcome, MoveResult, Notification, PeerMessage,
    Reply, Request, RequestId,
};

const KEY: &str = "faulty-link-test-key";
const AXES: u8 = 3;

const RATES: FaultRates = FaultRates {
    drop: 30,
    duplicate: 30,
    delay: 30,
    split: 30,
    corrupt: 30,
    reset: 8,
};

/// The peer's truth, read in-process on a serial session (never through the proxy).
struct Truth {
    peer: Arc<SimPeer>,
    session: Session,
}

impl Truth {
    fn new(peer: Arc<SimPeer>) -> Self {
        let session = peer.core().serial_session();
        Self { peer, session }
    }

    fn ask(&mut self, command: Command) -> Reply {
        let request = Request {
            id: RequestId(0),
            command,
        };
        match self
            .peer
            .core()
            .handle(&mut self.session, &request)
            .as_slice()
        {
            [PeerMessage::Reply { reply, .. }] => reply.clone(),
            other => panic!("the peer answered {other:?}"),
        }
    }

    fn positions(&mut self) -> Vec<i32> {
        match self.ask(Command::Status) {
            Reply::Status(status) => status.axes.iter().map(|a| a.position).collect(),
            other => panic!("Status answered {other:?}"),
        }
    }

    fn move_result(&mut self, id: RequestId) -> MoveResult {
        match self.ask(Command::MoveResult { request: id }) {
            Reply::MoveResult(result) => result,
            other => panic!("MoveResult answered {other:?}"),
        }
    }

    async fn wait_idle(&self) {
        for _ in 0..2_000 {
            if !self.peer.core().is_moving() {
                return;
            }
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        panic!("the peer never came to rest");
    }
}

/// Counts the `MoveFinished` notifications of every request id, from a client connected
/// straight to the peer.
async fn observe_executions(address: SocketAddr) -> (Client, Arc<Mutex<HashMap<u32, u32>>>) {
    let observer = Client::connect(
        format!("tcp://{address}").parse().unwrap(),
        ClientOptions::default(),
    )
    .await
    .unwrap();
    let executions = Arc::new(Mutex::new(HashMap::new()));
    let mut events = observer.events();
    let counts = executions.clone();
    tokio::spawn(async move {
        while let Ok(event) = events.recv().await {
            if let Event::Notification(Notification::MoveFinished { request, .. }) = event {
                *counts.lock().unwrap().entry(request.0).or_insert(0) += 1;
            }
        }
    });
    (observer, executions)
}

/// A random move: mostly `MoveBy`, sometimes `MoveTo`, over one to three axes.
fn random_move(rng: &mut SimRng, before: &[i32]) -> (Command, Vec<i32>) {
    let mut expected = before.to_vec();
    let mut values = heapless::Vec::new();
    let relative = !rng.next_u64().is_multiple_of(3);
    for axis in 0..AXES {
        if rng.next_u64().is_multiple_of(3) && !(axis == AXES - 1 && values.is_empty()) {
            continue;
        }
        let steps = (rng.next_u64() % 801) as i32 - 400;
        let index = usize::from(axis);
        expected[index] = if relative {
            before[index] + steps
        } else {
            steps
        };
        values.push(AxisValue { axis, steps }).unwrap();
    }
    let command = if relative {
        Command::MoveBy { deltas: values }
    } else {
        Command::MoveTo { targets: values }
    };
    (command, expected)
}

/// The client's end of one move, as the host would settle it.
enum Settled {
    /// The controller refused the move (`busy`).
    Refused,
    /// The client reported the move completed.
    Completed(Vec<i32>),
    /// The client could not tell; it asked `MoveResult` through the link afterwards.
    Reconciled(MoveResult),
}

/// What a client that lost track of a move learns by asking, through the faulty link.
async fn reconcile(client: &Client, id: RequestId) -> MoveResult {
    for _ in 0..100 {
        match client.move_result(id).await {
            Ok(MoveResult::InProgress) | Err(_) => {
                tokio::time::sleep(Duration::from_millis(20)).await
            }
            Ok(result) => return result,
        }
    }
    panic!("the client never learnt the outcome of {id:?}");
}

#[derive(Default, Debug)]
struct Figures {
    completed: usize,
    refused: usize,
    reconciled_executed: usize,
    reconciled_not_executed: usize,
}

async fn campaign(seed: u64, attempts: u32, moves: usize) -> (Figures, String) {
    let (peer, address) = SimPeer::start_on_loopback(&PeerOptions {
        axes: AXES,
        key: Some(KEY.into()),
        time: TimeMode::Instant,
        max_clients: 8,
        ..PeerOptions::default()
    })
    .await
    .unwrap();
    let mut truth = Truth::new(peer.clone());
    // Fast axes keep the waits for lost notifications short.
    for axis in 0..AXES {
        let config = match truth.ask(Command::GetConfig { axis }) {
            Reply::Config(config) => config,
            other => panic!("GetConfig answered {other:?}"),
        };
        let fast = AxisConfig {
            max_speed: 20_000,
            acceleration: 400_000,
            ..config
        };
        assert_eq!(
            truth.ask(Command::SetConfig { axis, config: fast }),
            Reply::Ok
        );
    }
    let (_observer, executions) = observe_executions(address).await;
    let proxy = FaultProxy::start(address, seed, RATES).await;
    let client = Client::connect(
        format!("tcp://{}", proxy.address()).parse().unwrap(),
        ClientOptions {
            key: Some(optalign::link::AccessKey::passphrase(KEY)),
            request_timeout: Duration::from_millis(200),
            attempts,
            connect_timeout: Duration::from_secs(2),
            send_timeout: Duration::from_secs(1),
            // The attempts are what is tested here: no overall deadline cuts them short.
            deadline: Duration::from_secs(120),
        },
    )
    .await
    .unwrap();

    let mut rng = SimRng::new(seed);
    let mut figures = Figures::default();
    let mut host_view = truth.positions();
    for number in 0..moves {
        let before = truth.positions();
        assert_eq!(
            host_view, before,
            "seed {seed:#x}, move {number}: the client's positions"
        );
        let (command, expected) = random_move(&mut rng, &before);
        let id = client.next_request_id();
        let settled = match client.run_move_with_id(id, command.clone()).await {
            Ok(report) => {
                assert_eq!(report.outcome, MoveOutcome::Completed, "{command:?}");
                Settled::Completed(report.positions)
            }
            Err(
                error @ (ClientError::Timeout { .. }
                | ClientError::OutcomeUnknown { .. }
                | ClientError::MoveTimeout { .. }
                | ClientError::Io { .. }
                | ClientError::Connect { .. }
                | ClientError::SendTimeout { .. }),
            ) => {
                eprintln!("seed {seed:#x}, move {number}: {error}");
                Settled::Reconciled(reconcile(&client, id).await)
            }
            // A reconnected client can find its old connection still holding control
            // for a moment: the refusal is honest, and the move must not have run.
            Err(error) if error.code() == Some(ErrorCode::BUSY) => {
                eprintln!("seed {seed:#x}, move {number}: {error}");
                Settled::Refused
            }
            Err(error) => panic!("seed {seed:#x}, move {number}: {command:?} failed: {error}"),
        };
        truth.wait_idle().await;
        let after = truth.positions();
        let true_result = truth.move_result(id);
        let ran = executions.lock().unwrap().get(&id.0).copied();
        match settled {
            Settled::Refused => {
                figures.refused += 1;
                assert_eq!(
                    true_result,
                    MoveResult::Unknown,
                    "seed {seed:#x}, move {number}"
                );
                assert_eq!(
                    after, before,
                    "seed {seed:#x}, move {number}: nothing moved"
                );
                assert_eq!(ran, None, "seed {seed:#x}, move {number}: {id:?} never ran");
            }
            Settled::Completed(positions) => {
                figures.completed += 1;
                assert_eq!(
                    positions, expected,
                    "seed {seed:#x}, move {number}: {command:?}"
                );
                assert_eq!(
                    after, expected,
                    "seed {seed:#x}, move {number}: the true positions"
                );
                assert_eq!(
                    true_result,
                    MoveResult::Finished {
                        outcome: MoveOutcome::Completed,
                        positions: expected.iter().copied().collect(),
                    }
                );
                host_view = positions;
            }
            Settled::Reconciled(result) => {
                assert_eq!(
                    result, true_result,
                    "seed {seed:#x}, move {number}: reconciled"
                );
                match result {
                    MoveResult::Finished { outcome, positions } => {
                        figures.reconciled_executed += 1;
                        assert_eq!(outcome, MoveOutcome::Completed);
                        assert_eq!(positions.to_vec(), expected);
                        assert_eq!(after, expected);
                        host_view = positions.to_vec();
                    }
                    MoveResult::Unknown => {
                        figures.reconciled_not_executed += 1;
                        assert_eq!(
                            after, before,
                            "seed {seed:#x}, move {number}: nothing moved"
                        );
                        assert_eq!(ran, None, "seed {seed:#x}, move {number}: {id:?} never ran");
                    }
                    MoveResult::InProgress => unreachable!("reconcile waits for the end"),
                }
            }
        }
    }
    // Late duplicates have had time to arrive; still each move ran at most once.
    tokio::time::sleep(Duration::from_millis(300)).await;
    truth.wait_idle().await;
    let twice: Vec<_> = executions
        .lock()
        .unwrap()
        .iter()
        .filter(|&(_, &count)| count > 1)
        .map(|(&id, &count)| (id, count))
        .collect();
    assert!(
        twice.is_empty(),
        "seed {seed:#x}: moves ran more than once: {twice:?}"
    );
    let final_truth = truth.positions();
    assert_eq!(host_view, final_truth);
    let mut reported = None;
    for _ in 0..50 {
        if let Ok(status) = client.status().await {
            reported = Some(status.axes.iter().map(|a| a.position).collect::<Vec<_>>());
            break;
        }
    }
    let reported = reported.expect("the client reads the status through the faulty link");
    assert_eq!(reported, final_truth, "seed {seed:#x}: the client's status");
    assert!(
        proxy.tally().faults() > 0,
        "seed {seed:#x}: no fault was injected"
    );
    (figures, proxy.tally().to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn moves_through_a_faulty_link_happen_exactly_once_and_positions_agree() {
    let moves = crate::fault_proxy::moves_from_env("OPTALIGN_FAULT_MOVES", 70);
    let mut total = Figures::default();
    // Few attempts per request make the client give up on some moves, so that their
    // outcomes must be reconciled; many make it ride out every fault.
    for (seed, attempts) in [(0x0F_A017, 12), (0xBAD_11C, 2), (0x5EED, 1)] {
        let (figures, tally) = campaign(seed, attempts, moves).await;
        println!("seed {seed:#x}, {attempts} attempts: {figures:?}; {tally}");
        total.completed += figures.completed;
        total.refused += figures.refused;
        total.reconciled_executed += figures.reconciled_executed;
        total.reconciled_not_executed += figures.reconciled_not_executed;
    }
    println!("total: {total:?}");
    assert!(
        total.reconciled_executed + total.reconciled_not_executed > 0,
        "no move needed reconciling: the campaign did not reach that path"
    );
    assert_eq!(
        total.completed + total.refused + total.reconciled_executed + total.reconciled_not_executed,
        3 * moves
    );
}

/// Relays connections to `upstream`; on connection number `victim` it drops the
/// controller's frame number `dropped` (counting from 0), and passes everything else.
async fn relay_dropping_one_reply(
    upstream: SocketAddr,
    victim: usize,
    dropped: usize,
) -> SocketAddr {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let address = listener.local_addr().unwrap();
    tokio::spawn(async move {
        for number in 0.. {
            let Ok((client, _)) = listener.accept().await else {
                return;
            };
            let server = tokio::net::TcpStream::connect(upstream).await.unwrap();
            let (mut client_read, mut client_write) = client.into_split();
            let (mut server_read, mut server_write) = server.into_split();
            tokio::spawn(async move {
                let _ = tokio::io::copy(&mut client_read, &mut server_write).await;
            });
            tokio::spawn(async move {
                let mut frames = 0;
                let mut byte = [0u8; 1];
                while let Ok(1) = server_read.read(&mut byte).await {
                    let keep = number != victim || frames != dropped;
                    frames += usize::from(byte[0] == 0);
                    if keep && client_write.write_all(&byte).await.is_err() {
                        return;
                    }
                }
            });
        }
    });
    address
}

/// A one-axis simulated peer with the key, on instant time, and its address.
async fn keyed_one_axis_peer() -> (Arc<SimPeer>, SocketAddr) {
    SimPeer::start_on_loopback(&PeerOptions {
        axes: 1,
        key: Some(KEY.into()),
        time: TimeMode::Instant,
        ..PeerOptions::default()
    })
    .await
    .unwrap()
}

/// A client with the key that tries ten times, 200 ms each.
fn patient_options() -> ClientOptions {
    ClientOptions {
        key: Some(optalign::link::AccessKey::passphrase(KEY)),
        request_timeout: Duration::from_millis(200),
        attempts: 10,
        ..ClientOptions::default()
    }
}

/// A reconnection whose authentication reply is lost must not leave the client on the
/// unauthenticated connection: its next attempt connects afresh and the move runs once.
#[tokio::test]
async fn a_lost_authentication_reply_does_not_leave_the_client_unauthenticated() {
    let (peer, address) = keyed_one_axis_peer().await;
    // Connection 1's frame 1 is the answer to its AuthChallenge (frame 0 answers Hello).
    let relay = relay_dropping_one_reply(address, 1, 1).await;
    let client = Client::connect(
        format!("tcp://{relay}").parse().unwrap(),
        ClientOptions {
            key: Some(optalign::link::AccessKey::passphrase(KEY)),
            request_timeout: Duration::from_millis(300),
            ..ClientOptions::default()
        },
    )
    .await
    .unwrap();
    client.disconnect().await;
    let report = client
        .move_by(&[AxisValue {
            axis: 0,
            steps: 120,
        }])
        .await
        .expect("the move runs on a fresh, authenticated connection");
    assert_eq!(report.outcome, MoveOutcome::Completed);
    assert_eq!(report.positions, [120]);
    assert_eq!(peer.shaft_positions(), [120]);
}

/// A client that has reconnected and is refused `busy` (its old connection may still hold
/// control, half-open) sends the move again once the old session ends, and it runs once.
#[tokio::test]
async fn a_reconnected_client_refused_busy_waits_for_the_old_session_to_end() {
    let (peer, address) = keyed_one_axis_peer().await;
    let options = patient_options();
    let url = format!("tcp://{address}");
    // Stands for the old connection the controller still believes in: it holds control.
    let old = Client::connect(url.parse().unwrap(), options.clone())
        .await
        .unwrap();
    old.move_by(&[AxisValue { axis: 0, steps: 10 }])
        .await
        .unwrap();
    let client = Client::connect(url.parse().unwrap(), options)
        .await
        .unwrap();
    client.disconnect().await;
    let release = async {
        tokio::time::sleep(Duration::from_millis(500)).await;
        drop(old);
    };
    let id = client.next_request_id();
    let command = Command::MoveBy {
        deltas: [AxisValue { axis: 0, steps: 90 }].into_iter().collect(),
    };
    let (report, ()) = tokio::join!(client.run_move_with_id(id, command), release);
    let report = report.expect("the move runs once the old session has ended");
    assert_eq!(report.positions, [100]);
    assert_eq!(peer.shaft_positions(), [100]);
}

/// A client that never reconnected and is refused `busy` reports it at once: another
/// client really controls the controller.
#[tokio::test]
async fn a_client_refused_busy_on_its_first_connection_reports_it_at_once() {
    let (_peer, address) = keyed_one_axis_peer().await;
    let options = patient_options();
    let url = format!("tcp://{address}");
    let holder = Client::connect(url.parse().unwrap(), options.clone())
        .await
        .unwrap();
    holder
        .move_by(&[AxisValue { axis: 0, steps: 10 }])
        .await
        .unwrap();
    let other = Client::connect(url.parse().unwrap(), options)
        .await
        .unwrap();
    let started = std::time::Instant::now();
    let error = other
        .move_by(&[AxisValue { axis: 0, steps: 5 }])
        .await
        .unwrap_err();
    assert_eq!(error.code(), Some(ErrorCode::BUSY), "{error}");
    assert!(
        started.elapsed() < Duration::from_millis(200),
        "{:?}",
        started.elapsed()
    );
}
