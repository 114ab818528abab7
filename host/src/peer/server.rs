//! Serving a [`PeerCore`] over TCP and a pseudo-terminal, with the motion loop that keeps
//! stepping the mounts on the simulated clock.
//!
//! Every connection runs the firmware core's [`Connection`], as a board's links do, so the
//! rules of a connection live in one place: frames checked against the session and sealed
//! once it authenticated, unauthenticated connections closed when idle, a write the client
//! does not take within its deadline closing the connection (so a client that never reads
//! its replies holds nothing), and network places decided by the core's admission table
//! (`max_clients` slots and a lobby, where a newcomer may shake hands and stop until a
//! request of its own earns it a slot, evicting an unauthenticated connection). Deadlines
//! run on the wall clock whatever the simulated time.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use optalign_firmware::admission::{self, Admission, Admissions, Standing, Ticket};
use optalign_firmware::{Connection, Deadlines, LinkKind, Port, Received, Session};
use optalign_protocol::{AxisConfig, Command, FrameError, MAX_FRAME, PeerMessage, Reply, Request};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::TcpListener;
use tokio::sync::{Notify, broadcast};
use tokio::task::{JoinHandle, JoinSet};

use super::bench::{self, Bench};
use super::clock::TimeMode;
use super::core::{PeerCore, PeerOptions};

/// The pause before the serial link serves a new session.
const SERIAL_RESTART: Duration = Duration::from_millis(100);

/// The network admission table; a token is the signal that closes its connection.
type NetworkSlots = Admissions<Arc<Notify>>;

/// A running simulated controller.
pub struct SimPeer {
    core: Arc<Mutex<PeerCore>>,
    network: Mutex<NetworkSlots>,
    /// The wall clock of connection deadlines and admissions.
    started: tokio::time::Instant,
    wake: Arc<Notify>,
    notifications: broadcast::Sender<PeerMessage>,
    tasks: Mutex<Vec<JoinHandle<()>>>,
    /// Keeps the terminal side of the pseudo-terminal open so clients can come and go.
    pty_terminal: Mutex<Option<tokio_serial::SerialStream>>,
}

impl SimPeer {
    /// Builds the peer and starts its motion loop (it serves nothing until told to).
    pub fn start(options: &PeerOptions) -> anyhow::Result<Arc<Self>> {
        Self::run(PeerCore::new(options)?, options)
    }

    /// Starts a controller on `bench`: after [`Self::kill`], on what the power cut left.
    pub fn start_on_bench(options: &PeerOptions, bench: Bench) -> anyhow::Result<Arc<Self>> {
        Self::run(PeerCore::on_bench(options, bench)?, options)
    }

    fn run(core: PeerCore, options: &PeerOptions) -> anyhow::Result<Arc<Self>> {
        let (notifications, _) = broadcast::channel(256);
        let peer = Arc::new(Self {
            core: Arc::new(Mutex::new(core)),
            network: Mutex::new(Admissions::new(options.max_clients, admission::LOBBY)),
            started: tokio::time::Instant::now(),
            wake: Arc::new(Notify::new()),
            notifications,
            tasks: Mutex::new(Vec::new()),
            pty_terminal: Mutex::new(None),
        });
        let motion = tokio::spawn(motion_loop(
            peer.core.clone(),
            peer.wake.clone(),
            peer.notifications.clone(),
        ));
        peer.track(motion);
        Ok(peer)
    }

    fn track(&self, task: JoinHandle<()>) {
        lock(&self.tasks).push(task);
    }

    /// Locks the state (for in-process rigs and tests that read hidden truth).
    pub fn core(&self) -> MutexGuard<'_, PeerCore> {
        lock(&self.core)
    }

    /// Runs `command` as the serial link would (physical access, a session of its own),
    /// waking the motion loop for a move it starts; returns the replies.
    pub fn serial_request(&self, command: Command) -> Vec<PeerMessage> {
        let replies = {
            let mut core = self.core();
            let mut session = core.serial_session();
            let request = Request {
                id: optalign_protocol::RequestId(rand::random()),
                command,
            };
            core.handle(&mut session, &request)
        };
        self.wake.notify_one();
        replies
    }

    /// Changes every axis's configuration over the serial link (as a user at the bench would
    /// before a test): reads each axis's configuration and writes back `change` of it.
    /// An axis whose configuration cannot be read or written is named in the error.
    pub fn reconfigure_over_serial(
        &self,
        change: impl Fn(AxisConfig) -> AxisConfig,
    ) -> Result<(), String> {
        let axes = self.core().shaft_positions().len() as u8;
        for axis in 0..axes {
            let config = match self.serial_request(Command::GetConfig { axis }).as_slice() {
                [
                    PeerMessage::Reply {
                        reply: Reply::Config(config),
                        ..
                    },
                ] => *config,
                other => return Err(format!("axis {axis}: GetConfig answered {other:?}")),
            };
            match self
                .serial_request(Command::SetConfig {
                    axis,
                    config: change(config),
                })
                .as_slice()
            {
                [
                    PeerMessage::Reply {
                        reply: Reply::Ok, ..
                    },
                ] => {}
                other => return Err(format!("axis {axis}: SetConfig answered {other:?}")),
            }
        }
        Ok(())
    }

    /// Network connections open now (in slots and the lobby).
    pub fn network_clients(&self) -> usize {
        lock(&self.network).open()
    }

    /// Microseconds of wall clock since the peer started: the clock of connections.
    fn wall_us(&self) -> u64 {
        u64::try_from(self.started.elapsed().as_micros()).unwrap_or(u64::MAX)
    }

    /// True shaft positions of the mounts: hidden truth.
    pub fn shaft_positions(&self) -> Vec<i32> {
        self.core().shaft_positions()
    }

    /// A peer with `options` accepting network clients on a free loopback port, and that
    /// port's address (for simulated rigs and tests).
    pub async fn start_on_loopback(
        options: &PeerOptions,
    ) -> anyhow::Result<(Arc<Self>, SocketAddr)> {
        let peer = Self::start(options)?;
        let address = peer
            .listen_tcp(SocketAddr::from(([127, 0, 0, 1], 0)))
            .await?;
        Ok((peer, address))
    }

    /// Accepts network clients on `address`; returns the bound address.
    pub async fn listen_tcp(self: &Arc<Self>, address: SocketAddr) -> anyhow::Result<SocketAddr> {
        let listener = TcpListener::bind(address)
            .await
            .map_err(|e| anyhow::anyhow!("cannot listen on {address}: {e}"))?;
        let bound = listener.local_addr()?;
        super::registry::register_tcp(bound, self);
        let peer = self.clone();
        let accept = tokio::spawn(async move {
            // Aborting this task (a shutdown or a power cut) drops every connection too.
            let mut connections = JoinSet::new();
            loop {
                while connections.try_join_next().is_some() {}
                match listener.accept().await {
                    Ok((stream, remote)) => {
                        let _ = stream.set_nodelay(true);
                        let now = peer.wall_us();
                        let closer = Arc::new(Notify::new());
                        let admission = lock(&peer.network).admit(now, closer.clone());
                        let ticket = match admission {
                            Admission::Slot(ticket) => ticket,
                            Admission::Lobby { ticket, evicted } => {
                                evict(evicted);
                                ticket
                            }
                            Admission::Refused => {
                                tracing::warn!(%remote, "client refused: the lobby is full");
                                continue;
                            }
                        };
                        tracing::info!(%remote, ?ticket, "client connected");
                        let connection =
                            Connection::open(LinkKind::Network, ticket, now, Deadlines::STANDARD);
                        let peer = peer.clone();
                        connections.spawn(async move {
                            peer.serve_connection(stream, connection, Some(closer))
                                .await;
                            tracing::info!(%remote, "client disconnected");
                        });
                    }
                    Err(error) => tracing::warn!(%error, "accept failed"),
                }
            }
        });
        self.track(accept);
        Ok(bound)
    }

    /// Serves the trusted serial link on a new pseudo-terminal; returns the path clients
    /// open (`serial://PATH`).
    pub fn open_pty(self: &Arc<Self>) -> anyhow::Result<String> {
        let (controller_side, terminal_side) = tokio_serial::SerialStream::pair()
            .map_err(|e| anyhow::anyhow!("cannot create a pseudo-terminal: {e}"))?;
        let path = tokio_serial::SerialPort::name(&terminal_side)
            .ok_or_else(|| anyhow::anyhow!("the pseudo-terminal has no path"))?;
        *lock(&self.pty_terminal) = Some(terminal_side);
        super::registry::register_serial(&path, self);
        let peer = self.clone();
        let serve = tokio::spawn(async move {
            let mut controller_side = controller_side;
            // A new session whenever one ends (a write nobody took in time, say), as a
            // board's serial link does.
            loop {
                peer.serve(&mut controller_side).await;
                tokio::time::sleep(SERIAL_RESTART).await;
            }
        });
        self.track(serve);
        Ok(path)
    }

    /// Serves one trusted (serial) byte stream until it ends, then ends its session
    /// (releasing control).
    pub async fn serve<S>(self: &Arc<Self>, stream: S)
    where
        S: AsyncRead + AsyncWrite,
    {
        let connection = Connection::serial(self.wall_us());
        self.serve_connection(stream, connection, None).await;
    }

    /// Serves `connection` on `stream` until it is closed (by the stream, its deadlines
    /// or `evicted`), then ends it.
    async fn serve_connection<S>(
        self: &Arc<Self>,
        stream: S,
        mut connection: Connection,
        evicted: Option<Arc<Notify>>,
    ) where
        S: AsyncRead + AsyncWrite,
    {
        let (mut read, mut write) = tokio::io::split(stream);
        let mut notifications = self.notifications.subscribe();
        let mut port = PeerPort(self);
        let mut bytes = [0u8; 1024];
        'stream: loop {
            let close = connection
                .close_at_us()
                .map(|at| self.started + Duration::from_micros(at));
            tokio::select! {
                read = read.read(&mut bytes) => {
                    let count = match read {
                        Ok(0) | Err(_) => break,
                        Ok(count) => count,
                    };
                    for &byte in &bytes[..count] {
                        let (message, then_close) =
                            match connection.receive(byte, self.wall_us(), &mut port) {
                                Received::Nothing => continue,
                                Received::Send(message) => (message, false),
                                Received::SendAndClose(message) => (message, true),
                            };
                        if self.send(&mut write, &mut connection, &message).await.is_err()
                            || then_close
                        {
                            break 'stream;
                        }
                    }
                }
                note = notifications.recv() => match note {
                    Ok(note) => {
                        if self.send(&mut write, &mut connection, &note).await.is_err() {
                            break;
                        }
                    }
                    // Notifications this client was too slow for: it falls back to Status.
                    Err(broadcast::error::RecvError::Lagged(_)) => {}
                    Err(broadcast::error::RecvError::Closed) => break,
                },
                () = sleep_until_or_never(close) => {
                    tracing::info!("closing a connection that did not authenticate in time");
                    break;
                }
                () = notified_or_never(evicted.as_deref()) => {
                    tracing::info!("closing an unauthenticated connection for a newcomer");
                    break;
                }
            }
        }
        connection.end(&mut port);
    }

    /// Writes one message as one frame within the connection's send deadline.
    async fn send<W: AsyncWrite + Unpin>(
        &self,
        write: &mut W,
        connection: &mut Connection,
        message: &PeerMessage,
    ) -> Result<(), ()> {
        let mut frame = [0u8; MAX_FRAME];
        let len = connection.encode(message, &mut frame).map_err(|_| ())?;
        let deadline =
            self.started + Duration::from_micros(connection.send_deadline_us(self.wall_us()));
        let written = tokio::time::timeout_at(deadline, async {
            write.write_all(&frame[..len]).await?;
            write.flush().await
        })
        .await;
        match written {
            Ok(Ok(())) => Ok(()),
            Ok(Err(_)) => Err(()),
            Err(_) => {
                tracing::info!("closing a connection that does not take its replies");
                Err(())
            }
        }
    }

    /// Cuts the controller's power: it falls silent at once, the listener and every
    /// connection close, and the bench comes back as the next start-up finds it (shafts
    /// where they are, the flash as last written, a write cut short left torn).
    pub fn kill(&self) -> Bench {
        let bench = {
            let mut core = self.core();
            core.cut_power();
            bench::lock(core.bench()).power_cycled()
        };
        self.shutdown();
        bench
    }

    /// On instant time: starts the move `command` on the serial link, lets `share` (0 to 1)
    /// of its planned duration pass and cuts the power there, as [`Self::kill`] does; returns
    /// the bench as the next start-up finds it. A power cut in the middle of a move, for
    /// tests and rehearsals of re-referencing.
    pub fn cut_power_during(&self, command: Command, share: f64) -> anyhow::Result<Bench> {
        anyhow::ensure!(
            (0.0..=1.0).contains(&share),
            "the share of the move must be 0 to 1, got {share}"
        );
        {
            let mut core = self.core();
            anyhow::ensure!(
                core.clock().mode() == TimeMode::Instant,
                "a power cut at a share of a move needs instant time"
            );
            let mut session = core.serial_session();
            let request = Request {
                id: optalign_protocol::RequestId(rand::random()),
                command,
            };
            let duration_ms = match core.handle(&mut session, &request).as_slice() {
                [
                    PeerMessage::Reply {
                        reply: optalign_protocol::Reply::MoveStarted { duration_ms },
                        ..
                    },
                ] => *duration_ms,
                other => anyhow::bail!("the move was not started: {other:?}"),
            };
            let now = core.clock().now_us();
            let cut_at = now + (share * f64::from(duration_ms) * 1000.0) as u64;
            core.clock_mut().jump_to(cut_at);
            // The steps due by then, and no more: the motion loop waits for this lock.
            core.poll();
            core.cut_power();
        }
        Ok(self.kill())
    }

    /// Stops serving and stepping.
    pub fn shutdown(&self) {
        for task in lock(&self.tasks).drain(..) {
            task.abort();
        }
    }
}

impl Drop for SimPeer {
    fn drop(&mut self) {
        self.shutdown();
    }
}

/// The peer's controller and admission table, as a connection reaches them.
struct PeerPort<'a>(&'a SimPeer);

impl Port for PeerPort<'_> {
    fn request(
        &mut self,
        session: &mut Session,
        request: &Request,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        let answers = self.0.core().handle(session, request);
        self.0.wake.notify_one();
        answers.into_iter().for_each(out);
    }

    fn link_error(&mut self, error: FrameError, out: &mut dyn FnMut(PeerMessage)) {
        self.0.core().link_error(error).into_iter().for_each(out);
    }

    fn standing(&mut self, ticket: Ticket, standing: Standing) {
        lock(&self.0.network).standing(ticket, standing);
    }

    fn promote(&mut self, ticket: Ticket) -> Option<Ticket> {
        let now = self.0.wall_us();
        let promotion = lock(&self.0.network).promote(ticket, now)?;
        evict(promotion.evicted);
        Some(promotion.ticket)
    }

    fn end(&mut self, session: &mut Session, ticket: Ticket) {
        self.0.core().end_session(session);
        lock(&self.0.network).release(ticket);
        self.0.wake.notify_one();
    }
}

/// Closes the connection an admission or promotion evicted, if any.
fn evict(evicted: Option<Arc<Notify>>) {
    if let Some(evicted) = evicted {
        tracing::info!("evicting an unauthenticated client");
        evicted.notify_one();
    }
}

/// Waits for `signal`, or forever without one.
async fn notified_or_never(signal: Option<&Notify>) {
    match signal {
        Some(signal) => signal.notified().await,
        None => std::future::pending().await,
    }
}

/// Sleeps until `deadline`, or forever without one.
async fn sleep_until_or_never(deadline: Option<tokio::time::Instant>) {
    match deadline {
        Some(deadline) => tokio::time::sleep_until(deadline).await,
        None => std::future::pending().await,
    }
}

fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    mutex
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// Steps the mounts whenever a step is due, and broadcasts what the controller reports.
async fn motion_loop(
    core: Arc<Mutex<PeerCore>>,
    wake: Arc<Notify>,
    notifications: broadcast::Sender<PeerMessage>,
) {
    loop {
        let (notes, deadline, wait) = {
            let mut core = lock(&core);
            let (notes, deadline) = core.poll();
            let wait = deadline.map(|d| core.clock().wall_time_until(d));
            if let Some(deadline) = deadline {
                core.jump_towards(deadline);
            }
            (notes, deadline, wait)
        };
        for note in notes {
            let _ = notifications.send(note);
        }
        match (deadline, wait) {
            (None, _) | (_, None) => wake.notified().await,
            (Some(_), Some(wait)) if wait.is_zero() => tokio::task::yield_now().await,
            (Some(_), Some(wait)) => {
                tokio::select! {
                    _ = tokio::time::sleep(wait) => {},
                    _ = wake.notified() => {},
                }
            }
        }
    }
}
