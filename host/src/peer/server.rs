//! Serving a [`PeerCore`] over TCP and a pseudo-terminal, with the motion loop that keeps
//! stepping the mounts on the simulated clock.
//!
//! Bounded like a board: at most `max_clients` network connections (one more is answered
//! `busy` and closed, and the last free slot is kept for a client that authenticates), and
//! a bounded reply queue per connection, so a client that does not read its replies stops
//! being read instead of growing the peer's memory.
//!
//! Sessions as on a board: frames are checked against the session (sealed only once it
//! authenticated), every frame written after authentication is sealed, notifications
//! included, and a network connection that has not authenticated is closed when its
//! session says so (idle for a few seconds, or too long on the reserved slot), on the wall
//! clock whatever the simulated time.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use optalign_firmware::{LinkKind, Session};
use optalign_protocol::seal::Sealer;
use optalign_protocol::{Command, ErrorCode, ErrorReply, PeerMessage, Reply, Request};
use tokio::io::{AsyncRead, AsyncWrite};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{Notify, broadcast, mpsc};
use tokio::task::{JoinHandle, JoinSet};

use super::bench::{self, Bench};
use super::clock::TimeMode;
use super::core::{PeerCore, PeerOptions};
use crate::link::framed::{FrameReader, write_frame, write_frame_sealed};

/// Replies waiting to be written to one connection.
const REPLY_QUEUE: usize = 32;

/// How long a refused connection gets to send its first request (to be answered by id).
const REFUSAL_WAIT: Duration = Duration::from_secs(2);

/// What the reader of a connection hands its writer: a message, and the sealer to seal it
/// and every later frame with when the session has just authenticated.
type Outgoing = (PeerMessage, Option<Sealer>);

/// A running simulated controller.
pub struct SimPeer {
    core: Arc<Mutex<PeerCore>>,
    max_clients: usize,
    /// Network connections open now.
    clients: Arc<AtomicUsize>,
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
            max_clients: options.max_clients,
            clients: Arc::default(),
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

    /// Network connections open now.
    pub fn network_clients(&self) -> usize {
        self.clients.load(Ordering::SeqCst)
    }

    /// Takes a network slot, if one is free; the last one comes reserved.
    fn take_slot(&self) -> Option<Slot> {
        let max = self.max_clients;
        self.clients
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |open| {
                (open < max).then_some(open + 1)
            })
            .ok()
            .map(|open| Slot {
                clients: self.clients.clone(),
                reserved: open + 1 == max,
            })
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
        super::registry::register(bound, self);
        let peer = self.clone();
        let accept = tokio::spawn(async move {
            // Aborting this task (a shutdown or a power cut) drops every connection too.
            let mut connections = JoinSet::new();
            loop {
                while connections.try_join_next().is_some() {}
                match listener.accept().await {
                    Ok((stream, remote)) => {
                        let _ = stream.set_nodelay(true);
                        let Some(slot) = peer.take_slot() else {
                            tracing::warn!(%remote, "client refused: every slot is taken");
                            tokio::spawn(refuse(stream, peer.max_clients));
                            continue;
                        };
                        tracing::info!(%remote, reserved = slot.reserved, "client connected");
                        let peer = peer.clone();
                        connections.spawn(async move {
                            peer.serve_on(stream, LinkKind::Network, slot.reserved)
                                .await;
                            drop(slot);
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
        let peer = self.clone();
        let serve =
            tokio::spawn(async move { peer.serve(controller_side, LinkKind::Serial).await });
        self.track(serve);
        Ok(path)
    }

    /// Serves one byte stream until it ends, then ends its session (releasing control).
    pub async fn serve<S>(self: &Arc<Self>, stream: S, link: LinkKind)
    where
        S: AsyncRead + AsyncWrite + Send + 'static,
    {
        self.serve_on(stream, link, false).await;
    }

    /// Serves one byte stream; on a `reserved` slot, nothing but the handshake,
    /// authentication and emergency stops is served until the session authenticates (and
    /// the connection is closed after anything else).
    async fn serve_on<S>(self: &Arc<Self>, stream: S, link: LinkKind, reserved: bool)
    where
        S: AsyncRead + AsyncWrite + Send + 'static,
    {
        let (read, mut write) = tokio::io::split(stream);
        let (replies, mut outgoing) = mpsc::channel::<Outgoing>(REPLY_QUEUE);
        let mut notifications = self.notifications.subscribe();
        let mut writer = AbortOnDrop(tokio::spawn(async move {
            let mut sealer = None;
            loop {
                let message = tokio::select! {
                    reply = outgoing.recv() => match reply {
                        Some((reply, fresh)) => {
                            sealer = fresh.or(sealer);
                            reply
                        }
                        None => return,
                    },
                    note = notifications.recv() => match note {
                        Ok(note) => note,
                        Err(broadcast::error::RecvError::Lagged(_)) => continue,
                        Err(broadcast::error::RecvError::Closed) => return,
                    },
                };
                if write_frame_sealed(&mut write, &message, sealer.as_mut())
                    .await
                    .is_err()
                {
                    return;
                }
            }
        }));
        let mut reader = FrameReader::<_, Request>::new(read);
        let opened = tokio::time::Instant::now();
        let wall_us = move || u64::try_from(opened.elapsed().as_micros()).unwrap_or(u64::MAX);
        let mut session = Session::opened(link, 0);
        if reserved {
            session.keep_for_authentication();
        }
        'stream: loop {
            let close = session
                .close_at_us()
                .map(|at| opened + Duration::from_micros(at));
            let frame = tokio::select! {
                frame = reader.next_checked(session.inbound()) => frame,
                () = sleep_until_or_never(close) => {
                    tracing::info!("closing a connection that did not authenticate in time");
                    break;
                }
            };
            let Ok(Some(frame)) = frame else {
                break;
            };
            let mut close_after = false;
            let answers = match frame {
                Ok(request) => {
                    session.heard(wall_us());
                    close_after = session.refuses_on_reserved_slot(&request.command);
                    self.core().handle(&mut session, &request)
                }
                Err(error) => self.core().link_error(error),
            };
            self.wake.notify_one();
            let mut sealer = session.take_sealer();
            for answer in answers {
                // Waits while the client is not reading: it is not read either then.
                if replies.send((answer, sealer.take())).await.is_err() {
                    break 'stream;
                }
            }
            if close_after {
                break;
            }
        }
        self.core().end_session(&mut session);
        drop(replies);
        let _ = (&mut writer.0).await;
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

/// A task that ends with its owner (a connection's writer ends with the connection).
struct AbortOnDrop(JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// One network connection's place among `max_clients`; freed when dropped.
struct Slot {
    clients: Arc<AtomicUsize>,
    /// The last free slot: kept for a client that authenticates.
    reserved: bool,
}

impl Drop for Slot {
    fn drop(&mut self) {
        self.clients.fetch_sub(1, Ordering::SeqCst);
    }
}

fn full(max_clients: usize) -> ErrorReply {
    ErrorReply::new(
        ErrorCode::BUSY,
        format_args!(
            "all {max_clients} network client slots are taken: close one, or use the serial link"
        ),
    )
}

fn refusal(id: optalign_protocol::RequestId, error: ErrorReply) -> PeerMessage {
    PeerMessage::Reply {
        id,
        reply: Reply::Error(error),
    }
}

/// Answers the first request of a connection there is no slot for with `busy`, then
/// closes it.
async fn refuse(stream: TcpStream, max_clients: usize) {
    let (read, mut write) = stream.into_split();
    let mut reader = FrameReader::<_, Request>::new(read);
    let message = match tokio::time::timeout(REFUSAL_WAIT, reader.next()).await {
        Ok(Ok(Some(Ok(request)))) => refusal(request.id, full(max_clients)),
        _ => PeerMessage::LinkError(full(max_clients)),
    };
    let _ = tokio::time::timeout(REFUSAL_WAIT, write_frame(&mut write, &message)).await;
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
            if let (Some(deadline), TimeMode::Instant) = (deadline, core.clock().mode()) {
                core.clock_mut().jump_to(deadline);
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
