//! The typed, async controller client.
//!
//! One [`Client`] owns one logical connection to a controller. It performs the version
//! handshake and (with a key, on network links) the challenge-response, sends requests
//! with timeouts, retransmits a request with the *same* id when no answer comes (the
//! controller's reply cache makes that safe), reconnects transparently when the link
//! drops, and turns the controller's unsolicited notifications into a stream. Moves return
//! once the motion has finished, like a status future in Bluesky/Ophyd. Every write has a
//! timeout too: a controller that stops reading (a zero TCP window, a stuck serial port)
//! gives [`ClientError::SendTimeout`], never a hang.
//!
//! The reply cache lives in the controller's RAM, so a retransmission is only safe to the
//! start-up that saw the first transmission: a command with an effect is never sent again
//! once the controller's boot nonce has changed, and its outcome is reported as unknown
//! ([`ClientError::OutcomeUnknown`]).
//!
//! Authentication: after the handshake the client derives the board's key (an
//! [`AccessKey`] passphrase is stretched with Argon2id, salted with the board id from
//! `Identity`, once per board), answers the challenge with a nonce of its own, and derives the
//! session key. From the controller's `Ok` on, every frame either way is sealed: the client
//! seals what it sends and drops (as [`Event::Garbage`]) what does not carry this session's
//! seal. An `Ok` that is not sealed means the answer did not come from a controller holding
//! the key, and the connection is refused. While the controller backs off after failed
//! authentications, the client waits as long as it is told and tries again.
//!
//! Deadlines: every request, retransmissions and reconnects included, and every connect
//! has one overall deadline ([`ClientOptions::deadline`]). An emergency stop never waits
//! behind the client's own connection (which a reconnect, the key derivation or an
//! authentication backoff may hold): on a network link it goes out on a keyless
//! connection of its own, retried until the deadline ([`emergency_stop`]).

use std::sync::atomic::{AtomicBool, AtomicU32, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use optalign_protocol::auth::{self, Key};
use optalign_protocol::seal::{Direction, Inbound, Opener, Sealer};
use optalign_protocol::{
    Access, AxisConfig, AxisValue, Command, ErrorCode, ErrorReply, FrameError, Identity, MAX_AXES,
    MoveOutcome, MoveResult, Notification, PROTOCOL_VERSION, PeerMessage, RefusalDetail, Reply,
    Request, RequestId, Status,
};
use tokio::io::{AsyncWriteExt, WriteHalf};
use tokio::sync::{broadcast, oneshot};
use tokio::task::JoinHandle;

use super::endpoint::Endpoint;
use super::framed::{FrameReader, write_frame_sealed};
use super::key::AccessKey;
use super::transport::Transport;
use super::waiters::Waiters;

/// How often authentication is tried while the controller backs off.
const AUTH_TRIES: u32 = 4;

/// The longest backoff the client waits out before trying again.
const LONGEST_BACKOFF: Duration = Duration::from_secs(10);

/// The pause before connecting again to a controller that had no room, and between two
/// tries of an emergency stop.
const RETRY_PAUSE: Duration = Duration::from_millis(50);

/// How a client behaves on a slow or failing link.
#[derive(Clone, Debug)]
pub struct ClientOptions {
    /// The access key; needed for motion and configuration over the network.
    pub key: Option<AccessKey>,
    /// How long to wait for one reply before retransmitting.
    pub request_timeout: Duration,
    /// How many times a request is sent (first try included) before giving up.
    pub attempts: u32,
    /// How long to wait for a TCP connection to open.
    pub connect_timeout: Duration,
    /// How long one write may wait for the controller to take the bytes.
    pub send_timeout: Duration,
    /// How long one request (or one connect) may take in all, retransmissions,
    /// reconnects and authentication backoffs included.
    pub deadline: Duration,
}

impl Default for ClientOptions {
    fn default() -> Self {
        Self {
            key: None,
            request_timeout: Duration::from_millis(1500),
            attempts: 4,
            connect_timeout: Duration::from_secs(3),
            send_timeout: Duration::from_secs(2),
            deadline: Duration::from_secs(10),
        }
    }
}

/// Why a controller operation failed.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    #[error("cannot reach controller at {endpoint}: {source}")]
    Connect {
        endpoint: Endpoint,
        source: std::io::Error,
    },
    #[error(
        "protocol version mismatch: controller at {endpoint} speaks {}, this optalign speaks version {ours}; update the firmware or the host so they match",
        version_name(*.theirs)
    )]
    VersionMismatch {
        endpoint: Endpoint,
        ours: u16,
        /// `None` from a controller older than version 5, which does not say which.
        theirs: Option<u16>,
    },
    #[error("controller refused the request: {0}")]
    Rejected(ErrorReply),
    #[error(
        "controller at {endpoint} accepted authentication without proving it holds the key (its answer was not sealed): a machine in between, or a broken controller"
    )]
    Impostor { endpoint: Endpoint },
    #[error(
        "sending to controller at {endpoint} timed out after {waited:?}: it takes no more bytes (a zero TCP window or a stuck serial port)"
    )]
    SendTimeout {
        endpoint: Endpoint,
        waited: Duration,
    },
    #[error("no answer from controller at {endpoint} after {attempts} attempts")]
    Timeout { endpoint: Endpoint, attempts: u32 },
    #[error(
        "{request} to controller at {endpoint} did not complete within its deadline of {deadline:?}"
    )]
    Deadline {
        endpoint: Endpoint,
        request: &'static str,
        deadline: Duration,
    },
    #[error("controller at {endpoint} sent an unexpected reply to {request}: {reply:?}")]
    UnexpectedReply {
        endpoint: Endpoint,
        request: &'static str,
        reply: Box<Reply>,
    },
    #[error("link to controller at {endpoint} failed: {source}")]
    Io {
        endpoint: Endpoint,
        source: std::io::Error,
    },
    #[error("motion did not finish on controller at {endpoint} within {waited:?}")]
    MoveTimeout {
        endpoint: Endpoint,
        waited: Duration,
    },
    #[error("outcome unknown: {request} (request {id:#010x}) on controller at {endpoint}: {why}")]
    OutcomeUnknown {
        endpoint: Endpoint,
        request: &'static str,
        id: u32,
        why: Unknown,
    },
}

/// Why the outcome of a request is unknown.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum Unknown {
    /// The controller restarted while the request was under way (its answer or its end
    /// not yet seen); it was not sent again.
    #[error("the controller restarted while it was under way, and it was not sent again")]
    Restarted,
    /// The controller no longer remembers the move (too many moves since).
    #[error("the controller no longer remembers it")]
    Forgotten,
    /// It was sent and no answer came (the controller or the link failed): it may have run.
    #[error("it was sent and no answer came back, so it may have run")]
    Unanswered,
}

impl ClientError {
    /// The controller's error code, when the controller refused the request.
    pub fn code(&self) -> Option<ErrorCode> {
        match self {
            Self::Rejected(reply) => Some(reply.code),
            _ => None,
        }
    }
}

/// Something the controller reported without being asked just now.
#[derive(Clone, Debug, PartialEq)]
pub enum Event {
    Notification(Notification),
    /// The controller could not read one of our frames.
    LinkError(ErrorReply),
    /// The controller sent bytes that are not a valid frame.
    Garbage(FrameError),
    /// The link dropped; the client reconnects on the next request.
    Disconnected,
}

/// How a move ended.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MoveReport {
    pub outcome: MoveOutcome,
    /// Logical positions of all axes when the motion ended.
    pub positions: Vec<i32>,
    /// The travel time the controller planned, ms.
    pub duration_ms: u32,
}

struct Connection {
    writer: WriteHalf<Transport>,
    reader: JoinHandle<()>,
    /// What the reader accepts (sealed frames only, once the session key is installed).
    inbound: Arc<Mutex<Inbound>>,
    /// Seals every frame sent once authenticated.
    sealer: Option<Sealer>,
    /// The requests waiting for their replies on this connection.
    waiters: Arc<Waiters>,
}

impl Drop for Connection {
    fn drop(&mut self) {
        self.reader.abort();
        self.waiters.close();
    }
}

/// A connection to one controller.
pub struct Client {
    endpoint: Endpoint,
    options: ClientOptions,
    connection: tokio::sync::Mutex<Option<Connection>>,
    events: broadcast::Sender<Event>,
    next_id: AtomicU32,
    identity: Mutex<Option<Identity>>,
    /// The key derived for the board last connected to, and that board's id.
    derived: Mutex<Option<(u64, Key)>>,
    /// Connections established so far (a reconnect makes it more than one).
    connections: AtomicU32,
    /// A write was cut short by a request's deadline: the link must be opened anew before
    /// the next frame, which would otherwise be garbled.
    interrupted: AtomicBool,
}

impl Client {
    /// Connects, performs the handshake and, with a key on a network link, authenticates.
    pub async fn connect(endpoint: Endpoint, options: ClientOptions) -> Result<Self, ClientError> {
        let (events, _) = broadcast::channel(256);
        let client = Self {
            endpoint,
            options,
            connection: tokio::sync::Mutex::new(None),
            events,
            next_id: AtomicU32::new(rand::random()),
            identity: Mutex::new(None),
            derived: Mutex::new(None),
            connections: AtomicU32::new(0),
            interrupted: AtomicBool::new(false),
        };
        let deadline = client.options.deadline;
        tokio::time::timeout(deadline, client.first_open())
            .await
            .map_err(|_| ClientError::Deadline {
                endpoint: client.endpoint.clone(),
                request: "connecting",
                deadline,
            })??;
        Ok(client)
    }

    /// Opens the first connection, again while the controller has no room for it yet (its
    /// slots taken: the connection was closed at once, or may only stop the motors) or a
    /// setup reply did not come, until the deadline.
    async fn first_open(&self) -> Result<(), ClientError> {
        let mut connection = self.connection.lock().await;
        loop {
            match self.open(&mut connection).await {
                Err(error @ (ClientError::Io { .. } | ClientError::Timeout { .. })) => {
                    tracing::debug!(%error, "connection dropped or silent while being set up; again");
                }
                Err(ClientError::Rejected(error)) if error.code == ErrorCode::BUSY => {
                    tracing::debug!(%error, "no slot for this connection yet; again");
                }
                outcome => return outcome,
            }
            tokio::time::sleep(RETRY_PAUSE).await;
        }
    }

    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    /// Who the controller said it is at the last handshake.
    pub fn identity(&self) -> Identity {
        self.identity
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .clone()
            .expect("a connected client has completed the handshake")
    }

    /// Notifications and link events from now on.
    pub fn events(&self) -> broadcast::Receiver<Event> {
        self.events.subscribe()
    }

    /// The boot nonce of the controller start-up this client last shook hands with.
    pub fn boot_nonce(&self) -> Option<u64> {
        self.identity
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .as_ref()
            .map(|identity| identity.boot_nonce)
    }

    /// Allocates a fresh request id.
    pub fn next_request_id(&self) -> RequestId {
        RequestId(self.next_id.fetch_add(1, Ordering::Relaxed))
    }

    /// Sends a command and waits for its reply; an error reply becomes `Rejected`.
    pub async fn request(&self, command: Command) -> Result<Reply, ClientError> {
        let id = self.next_request_id();
        self.request_with_id(id, command).await
    }

    /// Sends a command under a given id, retransmitting with the same id on timeout or
    /// after a reconnect, so the controller executes it at most once. A command with an
    /// effect is only ever sent to the start-up that got it first: if the controller
    /// restarted in between, the result is [`ClientError::OutcomeUnknown`].
    pub async fn request_with_id(
        &self,
        id: RequestId,
        command: Command,
    ) -> Result<Reply, ClientError> {
        let name = command.name();
        let effect =
            command.has_effect() && !matches!(command, Command::Stop | Command::EmergencyStop);
        let deadline = self.options.deadline;
        let mut sent_to = None;
        let outcome = tokio::time::timeout(
            deadline,
            self.attempts(Request { id, command }, &mut sent_to),
        )
        .await
        .unwrap_or_else(|_| {
            Err(ClientError::Deadline {
                endpoint: self.endpoint.clone(),
                request: name,
                deadline,
            })
        });
        match outcome {
            // It went out and no answer came back: the controller may have run it. (A send
            // that timed out keeps its own error: the controller took no more bytes.)
            Err(
                ClientError::Timeout { .. }
                | ClientError::Io { .. }
                | ClientError::Connect { .. }
                | ClientError::Deadline { .. },
            ) if effect && sent_to.is_some() => Err(ClientError::OutcomeUnknown {
                endpoint: self.endpoint.clone(),
                request: name,
                id: id.0,
                why: Unknown::Unanswered,
            }),
            other => other,
        }
    }

    /// Sends `request` until it is answered, within the attempts; `sent_to` records the
    /// start-up it went to (see [`Self::send`]).
    async fn attempts(
        &self,
        request: Request,
        sent_to: &mut Option<u64>,
    ) -> Result<Reply, ClientError> {
        let id = request.id;
        let attempts = self.options.attempts.max(1);
        let mut last_error = None;
        for attempt in 1..=attempts {
            match self.exchange(&request, sent_to).await {
                Ok(Reply::Error(error)) if error.code == ErrorCode::HANDSHAKE_REQUIRED => {
                    // The controller no longer knows this session (it restarted on a link
                    // that stayed up): shake hands again, then see who answers.
                    tracing::debug!(?id, "controller forgot the session; reconnecting");
                    self.disconnect().await;
                    last_error = Some(ClientError::Rejected(error));
                }
                Ok(Reply::Error(error))
                    if self.own_old_connection_may_control(&request, &error) =>
                {
                    // Our previous connection may still hold control: the controller has
                    // not yet seen it close (a half-open TCP connection). The refusal ran
                    // nothing and is never cached, so the same id is sent again later.
                    tracing::debug!(
                        ?id,
                        "busy after a reconnect; waiting for the old session to end"
                    );
                    tokio::time::sleep(self.options.request_timeout).await;
                    last_error = Some(ClientError::Rejected(error));
                }
                Ok(Reply::Error(error) | Reply::Refused { error, .. }) => {
                    return Err(ClientError::Rejected(error));
                }
                Ok(reply) => return Ok(reply),
                Err(
                    error @ (ClientError::VersionMismatch { .. }
                    | ClientError::Impostor { .. }
                    | ClientError::Rejected(_)
                    | ClientError::OutcomeUnknown { .. }),
                ) => {
                    return Err(error);
                }
                Err(error) => {
                    tracing::debug!(?id, %error, "retrying request");
                    if attempt < attempts
                        && matches!(error, ClientError::Io { .. } | ClientError::Connect { .. })
                    {
                        // The link failed at once (a controller restarting refuses or drops
                        // connections): wait as long as for a reply, so the attempts span
                        // the restart instead of being spent in a few milliseconds.
                        tokio::time::sleep(self.options.request_timeout).await;
                    }
                    last_error = Some(error);
                }
            }
        }
        Err(match last_error {
            Some(error @ (ClientError::Connect { .. } | ClientError::SendTimeout { .. })) => error,
            Some(ClientError::Rejected(error)) if error.code == ErrorCode::BUSY => {
                ClientError::Rejected(error)
            }
            _ => ClientError::Timeout {
                endpoint: self.endpoint.clone(),
                attempts: self.options.attempts.max(1),
            },
        })
    }

    /// Whether `error` may be our own earlier connection still holding control: a control
    /// command refused `busy` by a client that has reconnected.
    fn own_old_connection_may_control(&self, request: &Request, error: &ErrorReply) -> bool {
        error.code == ErrorCode::BUSY
            && request.command.access() == Access::Control
            && self.connections.load(Ordering::Relaxed) > 1
    }

    /// One attempt: (re)connect if needed, send, wait for the reply or the timeout.
    /// `sent_to` is the boot nonce the request went to first (see [`Self::send`]).
    async fn exchange(
        &self,
        request: &Request,
        sent_to: &mut Option<u64>,
    ) -> Result<Reply, ClientError> {
        let (waiters, receiver) = self.send(request, sent_to).await?;
        self.reply(request, &waiters, receiver).await
    }

    /// Waits for the reply to `request` within the request timeout.
    async fn reply(
        &self,
        request: &Request,
        waiters: &Waiters,
        receiver: oneshot::Receiver<Reply>,
    ) -> Result<Reply, ClientError> {
        let reply = tokio::time::timeout(self.options.request_timeout, receiver).await;
        waiters.forget(request.id.0);
        match reply {
            Ok(Ok(reply)) => Ok(reply),
            Ok(Err(_)) => Err(self.link_ended()),
            Err(_) => Err(ClientError::Timeout {
                endpoint: self.endpoint.clone(),
                attempts: 1,
            }),
        }
    }

    /// The error of a request whose link ended before its reply came.
    fn link_ended(&self) -> ClientError {
        ClientError::Io {
            endpoint: self.endpoint.clone(),
            source: std::io::ErrorKind::ConnectionReset.into(),
        }
    }

    /// Registers the wait for `request`'s reply on `connection`, then writes it; the
    /// connection's waiters and the reply's receiver.
    async fn write_request(
        &self,
        connection: &mut Connection,
        request: &Request,
    ) -> Result<(Arc<Waiters>, oneshot::Receiver<Reply>), ClientError> {
        let waiters = connection.waiters.clone();
        let receiver = waiters
            .wait_for(request.id.0)
            .ok_or_else(|| self.link_ended())?;
        // Marked until the frame is out: a deadline cutting the write short leaves it set.
        self.interrupted.store(true, Ordering::Release);
        let written =
            write_frame_sealed(&mut connection.writer, request, connection.sealer.as_mut());
        let written = self.bounded(written).await;
        self.interrupted.store(false, Ordering::Release);
        written.map(|()| (waiters, receiver))
    }

    /// Writes `request`, reconnecting first when the link is down. A command with an
    /// effect goes only to the start-up it was first sent to: `sent_to` records that
    /// start-up's boot nonce, and another one answering now gives `OutcomeUnknown`. Stops
    /// are exempt: one run twice is the same as once, and a restarted controller should
    /// stop too. Gives the connection's waiters and the receiver of the reply.
    async fn send(
        &self,
        request: &Request,
        sent_to: &mut Option<u64>,
    ) -> Result<(Arc<Waiters>, oneshot::Receiver<Reply>), ClientError> {
        let mut connection = self.connection.lock().await;
        if self.interrupted.swap(false, Ordering::AcqRel) {
            *connection = None;
        }
        let alive = connection.as_ref().is_some_and(|c| !c.reader.is_finished());
        if !alive {
            *connection = None;
            self.open(&mut connection).await?;
        }
        let stop = matches!(request.command, Command::Stop | Command::EmergencyStop);
        if request.command.has_effect() && !stop {
            let boot = self.boot_nonce();
            match *sent_to {
                Some(first) if Some(first) != boot => {
                    return Err(ClientError::OutcomeUnknown {
                        endpoint: self.endpoint.clone(),
                        request: request.command.name(),
                        id: request.id.0,
                        why: Unknown::Restarted,
                    });
                }
                _ => *sent_to = boot,
            }
        }
        let Some(open) = connection.as_mut() else {
            unreachable!("open() either connects or returns an error")
        };
        let written = self.write_request(open, request).await;
        if written.is_err() {
            // A frame cut short would garble the next one, and a link that ended answers
            // nothing: start over on a new link.
            *connection = None;
        }
        written
    }

    /// Runs one write within the send timeout.
    async fn bounded(
        &self,
        write: impl Future<Output = std::io::Result<()>>,
    ) -> Result<(), ClientError> {
        match tokio::time::timeout(self.options.send_timeout, write).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(source)) => Err(ClientError::Io {
                endpoint: self.endpoint.clone(),
                source,
            }),
            Err(_) => Err(ClientError::SendTimeout {
                endpoint: self.endpoint.clone(),
                waited: self.options.send_timeout,
            }),
        }
    }

    /// Opens the transport, starts the reader, and runs handshake and authentication.
    async fn open(&self, slot: &mut Option<Connection>) -> Result<(), ClientError> {
        let transport = Transport::open(&self.endpoint, self.options.connect_timeout)
            .await
            .map_err(|source| ClientError::Connect {
                endpoint: self.endpoint.clone(),
                source,
            })?;
        let (read, mut writer) = tokio::io::split(transport);
        // A lone delimiter flushes any half frame a previous client left at the peer.
        self.bounded(writer.write_all(&[0])).await?;
        let inbound = Arc::new(Mutex::new(Inbound::plain()));
        let waiters = Arc::new(Waiters::new());
        let reader = tokio::spawn(read_loop(
            FrameReader::new(read),
            inbound.clone(),
            waiters.clone(),
            self.events.clone(),
        ));
        *slot = Some(Connection {
            writer,
            reader,
            inbound,
            sealer: None,
            waiters,
        });
        let established = self.establish(slot).await;
        if established.is_ok() {
            self.connections.fetch_add(1, Ordering::Relaxed);
        }
        if established.is_err() {
            // A connection whose handshake or authentication failed must not be reused:
            // the next attempt would send on a session without access.
            *slot = None;
        }
        established
    }

    /// Handshake and (with a key, on network links) authentication on a new connection.
    async fn establish(&self, slot: &mut Option<Connection>) -> Result<(), ClientError> {
        let identity = self.handshake(slot).await?;
        let board_id = identity.board_id;
        *self.identity.lock().unwrap_or_else(|e| e.into_inner()) = Some(identity);
        if let (Some(key), false) = (&self.options.key, self.endpoint.is_serial()) {
            let key = self.board_key(key, board_id).await?;
            self.authenticate(slot, &key).await?;
        }
        Ok(())
    }

    /// `key` as the board `board_id` stores it (stretched once per board, off the executor).
    async fn board_key(&self, key: &AccessKey, board_id: u64) -> Result<Key, ClientError> {
        let cached = *self.derived.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((id, derived)) = cached
            && id == board_id
        {
            return Ok(derived);
        }
        let access = key.clone();
        let derived = tokio::task::spawn_blocking(move || access.for_board(board_id))
            .await
            .map_err(|error| ClientError::Io {
                endpoint: self.endpoint.clone(),
                source: std::io::Error::other(format!("deriving the key failed: {error}")),
            })?;
        *self.derived.lock().unwrap_or_else(|e| e.into_inner()) = Some((board_id, derived));
        Ok(derived)
    }

    /// A request on a connection being set up (no reconnect, no retransmit).
    async fn setup_request(
        &self,
        slot: &mut Option<Connection>,
        command: Command,
    ) -> Result<Reply, ClientError> {
        let request = Request {
            id: self.next_request_id(),
            command,
        };
        let connection = slot.as_mut().expect("setup runs on an open connection");
        let (waiters, receiver) = self.write_request(connection, &request).await?;
        self.reply(&request, &waiters, receiver).await
    }

    async fn handshake(&self, slot: &mut Option<Connection>) -> Result<Identity, ClientError> {
        let reply = self
            .setup_request(
                slot,
                Command::Hello {
                    protocol_version: PROTOCOL_VERSION,
                },
            )
            .await;
        match reply {
            Ok(Reply::Hello(identity)) if identity.protocol_version == PROTOCOL_VERSION => {
                Ok(identity)
            }
            Ok(Reply::Hello(identity)) => Err(ClientError::VersionMismatch {
                endpoint: self.endpoint.clone(),
                ours: PROTOCOL_VERSION,
                theirs: Some(identity.protocol_version),
            }),
            Ok(Reply::Refused {
                error,
                detail: RefusalDetail::ProtocolVersion(theirs),
            }) if error.code == ErrorCode::VERSION_MISMATCH => Err(ClientError::VersionMismatch {
                endpoint: self.endpoint.clone(),
                ours: PROTOCOL_VERSION,
                theirs: Some(theirs),
            }),
            // A controller older than version 5 says no more than the code.
            Ok(Reply::Error(error)) if error.code == ErrorCode::VERSION_MISMATCH => {
                Err(ClientError::VersionMismatch {
                    endpoint: self.endpoint.clone(),
                    ours: PROTOCOL_VERSION,
                    theirs: None,
                })
            }
            Ok(Reply::Error(error) | Reply::Refused { error, .. }) => {
                Err(ClientError::Rejected(error))
            }
            Ok(other) => Err(self.unexpected("Hello", other)),
            Err(error) => Err(error),
        }
    }

    /// Answers a challenge; tries again while the controller backs off after failures.
    async fn authenticate(
        &self,
        slot: &mut Option<Connection>,
        key: &Key,
    ) -> Result<(), ClientError> {
        let mut tries = 0;
        loop {
            tries += 1;
            match self.answer_challenge(slot, key).await {
                Err(Refusal::Backoff { wait, .. }) if tries < AUTH_TRIES => {
                    let wait = wait.min(LONGEST_BACKOFF);
                    tracing::info!(?wait, "controller backs off authentication; waiting");
                    tokio::time::sleep(wait).await;
                }
                Err(Refusal::Backoff { error, .. }) => return Err(ClientError::Rejected(error)),
                Err(Refusal::Other(error)) => return Err(error),
                Ok(()) => return Ok(()),
            }
        }
    }

    /// One challenge and its answer; on success the connection is sealed both ways.
    async fn answer_challenge(
        &self,
        slot: &mut Option<Connection>,
        key: &Key,
    ) -> Result<(), Refusal> {
        let nonce = match self.setup_request(slot, Command::AuthChallenge).await? {
            Reply::Challenge { nonce } => nonce,
            other => return Err(self.refusal("AuthChallenge", other)),
        };
        let client_nonce: auth::Nonce = rand::random();
        let tag = auth::challenge_tag(key, &nonce, &client_nonce);
        let session = auth::session_key(key, &nonce, &client_nonce);
        let inbound = {
            let connection = slot.as_mut().expect("setup runs on an open connection");
            connection.inbound.clone()
        };
        // Before the answer goes out: the controller seals its reply to it.
        lock(&inbound).install(Opener::new(session, Direction::ToHost), false);
        let reply = self
            .setup_request(slot, Command::AuthResponse { tag, client_nonce })
            .await?;
        match reply {
            Reply::Ok if lock(&inbound).is_sealed() => {
                let connection = slot.as_mut().expect("setup runs on an open connection");
                connection.sealer = Some(Sealer::new(session, Direction::ToController));
                Ok(())
            }
            Reply::Ok => Err(ClientError::Impostor {
                endpoint: self.endpoint.clone(),
            }
            .into()),
            other => {
                *lock(&inbound) = Inbound::plain();
                Err(self.refusal("AuthResponse", other))
            }
        }
    }

    /// What a reply other than the one hoped for to `request` means.
    fn refusal(&self, request: &'static str, reply: Reply) -> Refusal {
        match reply {
            Reply::Refused {
                error,
                detail: RefusalDetail::RetryAfterMs(ms),
            } => Refusal::Backoff {
                wait: Duration::from_millis(u64::from(ms)),
                error,
            },
            Reply::Error(error) | Reply::Refused { error, .. } => {
                Refusal::Other(ClientError::Rejected(error))
            }
            other => Refusal::Other(self.unexpected(request, other)),
        }
    }

    fn unexpected(&self, request: &'static str, reply: Reply) -> ClientError {
        ClientError::UnexpectedReply {
            endpoint: self.endpoint.clone(),
            request,
            reply: Box::new(reply),
        }
    }

    pub async fn status(&self) -> Result<Status, ClientError> {
        match self.request(Command::Status).await? {
            Reply::Status(status) => Ok(status),
            other => Err(self.unexpected("Status", other)),
        }
    }

    pub async fn get_config(&self, axis: u8) -> Result<AxisConfig, ClientError> {
        match self.request(Command::GetConfig { axis }).await? {
            Reply::Config(config) => Ok(config),
            other => Err(self.unexpected("GetConfig", other)),
        }
    }

    /// What became of the move started by `request`, as the controller remembers it.
    pub async fn move_result(&self, request: RequestId) -> Result<MoveResult, ClientError> {
        match self.request(Command::MoveResult { request }).await? {
            Reply::MoveResult(result) => Ok(result),
            other => Err(self.unexpected("MoveResult", other)),
        }
    }

    /// Stops every axis at once and latches motion off, without waiting behind this
    /// client's own connection on a network link (see [`emergency_stop`]).
    pub async fn emergency_stop(&self) -> Result<(), ClientError> {
        if self.endpoint.is_serial() {
            // One port, one reader: the serial link has no key to derive nor backoff.
            return self.command_ok(Command::EmergencyStop).await;
        }
        emergency_stop(&self.endpoint, &self.options).await
    }

    /// Sends a command whose only good answer is `Ok`.
    pub async fn command_ok(&self, command: Command) -> Result<(), ClientError> {
        let name = command.name();
        match self.request(command).await? {
            Reply::Ok => Ok(()),
            other => Err(self.unexpected(name, other)),
        }
    }

    /// Moves axes to absolute targets; returns when the motion has ended.
    pub async fn move_to(&self, targets: &[AxisValue]) -> Result<MoveReport, ClientError> {
        self.run_move(Command::MoveTo {
            targets: to_axis_list(targets),
        })
        .await
    }

    /// Moves axes by relative amounts; returns when the motion has ended.
    pub async fn move_by(&self, deltas: &[AxisValue]) -> Result<MoveReport, ClientError> {
        self.run_move(Command::MoveBy {
            deltas: to_axis_list(deltas),
        })
        .await
    }

    /// Moves axes by relative amounts in recovery mode, also on axes whose position is lost
    /// (they stay lost until `SetPosition`); returns when the motion has ended.
    pub async fn recovery_move_by(&self, deltas: &[AxisValue]) -> Result<MoveReport, ClientError> {
        self.run_move(Command::RecoveryMoveBy {
            deltas: to_axis_list(deltas),
        })
        .await
    }

    /// Starts a move under a caller-chosen id and waits for it (used to show that a
    /// retransmitted move executes once).
    pub async fn run_move_with_id(
        &self,
        id: RequestId,
        command: Command,
    ) -> Result<MoveReport, ClientError> {
        let mut events = self.events();
        let name = command.name();
        let duration_ms = match self.request_with_id(id, command).await? {
            Reply::MoveStarted { duration_ms } => duration_ms,
            other => return Err(self.unexpected("Move", other)),
        };
        let motion = Motion {
            id,
            name,
            boot: self.boot_nonce(),
            duration_ms,
        };
        self.await_motion(&motion, &mut events).await
    }

    async fn run_move(&self, command: Command) -> Result<MoveReport, ClientError> {
        let id = self.next_request_id();
        self.run_move_with_id(id, command).await
    }

    /// Waits for the notification that ends `motion`; if it does not come in time
    /// (for example the link dropped and the notification went to the old connection),
    /// asks the controller how the move ended until it has.
    async fn await_motion(
        &self,
        motion: &Motion,
        events: &mut broadcast::Receiver<Event>,
    ) -> Result<MoveReport, ClientError> {
        let (id, duration_ms) = (motion.id, motion.duration_ms);
        let expected = Duration::from_millis(u64::from(duration_ms));
        let grace = expected / 2 + Duration::from_millis(500);
        let deadline = tokio::time::Instant::now() + expected + grace;
        loop {
            let event = tokio::select! {
                event = events.recv() => event,
                _ = tokio::time::sleep_until(deadline) => break,
            };
            match event {
                Ok(Event::Notification(Notification::MoveFinished {
                    request,
                    outcome,
                    positions,
                })) if request == id => {
                    return Ok(MoveReport {
                        outcome,
                        positions: positions.to_vec(),
                        duration_ms,
                    });
                }
                Ok(Event::Disconnected) | Err(broadcast::error::RecvError::Closed) => break,
                _ => {}
            }
        }
        self.ask_result(motion, expected * 2 + Duration::from_secs(5))
            .await
    }

    /// Asks `MoveResult` for `motion` until it has ended, or `limit` has passed.
    async fn ask_result(
        &self,
        motion: &Motion,
        limit: Duration,
    ) -> Result<MoveReport, ClientError> {
        let unknown = |why| ClientError::OutcomeUnknown {
            endpoint: self.endpoint.clone(),
            request: motion.name,
            id: motion.id.0,
            why,
        };
        let started = tokio::time::Instant::now();
        loop {
            let result = self.move_result(motion.id).await?;
            if self.boot_nonce() != motion.boot {
                // Another start-up answers: the move was cut short by the restart.
                return Err(unknown(Unknown::Restarted));
            }
            match result {
                MoveResult::Finished { outcome, positions } => {
                    return Ok(MoveReport {
                        outcome,
                        positions: positions.to_vec(),
                        duration_ms: motion.duration_ms,
                    });
                }
                MoveResult::Unknown => return Err(unknown(Unknown::Forgotten)),
                MoveResult::InProgress => {}
            }
            if started.elapsed() > limit {
                return Err(ClientError::MoveTimeout {
                    endpoint: self.endpoint.clone(),
                    waited: limit,
                });
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Drops the link now (the next request reconnects).
    pub async fn disconnect(&self) {
        *self.connection.lock().await = None;
    }
}

/// Sends `EmergencyStop` to the controller at `endpoint` on a keyless connection of its
/// own (an emergency stop is open to everyone), trying again until `options.deadline`:
/// nothing another connection does (a reconnect, the key derivation, an authentication
/// backoff) delays it, and a controller whose slots are all taken still answers it.
pub async fn emergency_stop(
    endpoint: &Endpoint,
    options: &ClientOptions,
) -> Result<(), ClientError> {
    let keyless = ClientOptions {
        key: None,
        attempts: 1,
        ..options.clone()
    };
    let deadline = tokio::time::Instant::now() + options.deadline;
    let mut last_error = None;
    loop {
        let attempt = async {
            let client = Client::connect(endpoint.clone(), keyless.clone()).await?;
            client.command_ok(Command::EmergencyStop).await
        };
        match tokio::time::timeout_at(deadline, attempt).await {
            Ok(Ok(())) => return Ok(()),
            Ok(Err(
                error @ (ClientError::VersionMismatch { .. } | ClientError::Impostor { .. }),
            )) => {
                return Err(error);
            }
            Ok(Err(error)) => {
                tracing::debug!(%error, "emergency stop not through yet; trying again");
                last_error = Some(error);
            }
            Err(_) => break,
        }
        if tokio::time::Instant::now() + RETRY_PAUSE >= deadline {
            break;
        }
        tokio::time::sleep(RETRY_PAUSE).await;
    }
    Err(last_error.unwrap_or(ClientError::Deadline {
        endpoint: endpoint.clone(),
        request: "EmergencyStop",
        deadline: options.deadline,
    }))
}

/// A move the controller accepted, as the client waits for its end.
struct Motion {
    id: RequestId,
    /// The command's name, for messages.
    name: &'static str,
    /// The start-up that accepted it.
    boot: Option<u64>,
    duration_ms: u32,
}

fn to_axis_list(values: &[AxisValue]) -> heapless::Vec<AxisValue, MAX_AXES> {
    values.iter().copied().take(MAX_AXES).collect()
}

fn lock<T>(mutex: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    mutex.lock().unwrap_or_else(|e| e.into_inner())
}

/// Why an authentication attempt did not succeed.
enum Refusal {
    /// The controller backs off after failed authentications: try again after `wait`.
    Backoff {
        wait: Duration,
        error: ErrorReply,
    },
    Other(ClientError),
}

impl From<ClientError> for Refusal {
    fn from(error: ClientError) -> Self {
        Self::Other(error)
    }
}

/// A protocol version in words, for the mismatch message.
fn version_name(version: Option<u16>) -> String {
    match version {
        Some(version) => format!("version {version}"),
        None => "a version older than 5 (it does not say which)".into(),
    }
}

async fn read_loop(
    mut reader: FrameReader<tokio::io::ReadHalf<Transport>, PeerMessage>,
    inbound: Arc<Mutex<Inbound>>,
    waiters: Arc<Waiters>,
    events: broadcast::Sender<Event>,
) {
    loop {
        match reader.next_shared(&inbound).await {
            Ok(Some(Ok(PeerMessage::Reply { id, reply }))) => {
                if !waiters.answer(id.0, reply) {
                    tracing::debug!(?id, "reply to a request nobody waits for");
                }
            }
            Ok(Some(Ok(PeerMessage::Notify(notification)))) => {
                let _ = events.send(Event::Notification(notification));
            }
            Ok(Some(Ok(PeerMessage::LinkError(error)))) => {
                tracing::warn!(%error, "controller could not read a frame");
                let _ = events.send(Event::LinkError(error));
            }
            Ok(Some(Err(error))) => {
                tracing::warn!(%error, "controller sent an invalid frame");
                let _ = events.send(Event::Garbage(error));
            }
            Ok(None) | Err(_) => {
                waiters.close();
                let _ = events.send(Event::Disconnected);
                return;
            }
        }
    }
}
