//! The command dispatcher: handshake, access control, the request-id memory, and the
//! execution of every command.
//!
//! Order of checks: handshake, then the stop-only rule (a connection waiting in the lobby
//! for a network slot may only shake hands and stop),
//! then access (so a session without access learns nothing from the reply memory, not even a cached reply), then the reply memory (so a client that
//! reconnected gets its retransmission answered even while its old connection still holds
//! control), then the single-controller rule (see [`crate::control`]), then the command.
//!
//! `Stop` and `EmergencyStop` are never answered from the reply memory nor kept in it: they
//! run every time they arrive, and a flood of them cannot push another client's remembered
//! replies out. An emergency stop latches motion off (`emergency-stopped`) until
//! `ClearEmergency`, a control command, so only the controlling client (or the serial link)
//! releases it.
//!
//! A move arriving while another runs replaces it: the running move brakes to a stop along
//! its ramps (its `MoveFinished` says `Stopped`), and the new one is planned from where the
//! axes come to rest (known exactly at once, since braking is deterministic) and starts
//! when they do; its `MoveStarted` duration includes the braking. `MoveBy` and
//! `RecoveryMoveBy` deltas are relative to that rest position. A move that was waiting for
//! such a stop and is replaced in turn never runs; it finishes `Stopped` at once.
//!
//! A lost position (`POSITION_LOST`) refuses `MoveTo` and `MoveBy`; `RecoveryMoveBy`, the
//! explicit recovery mode, moves such an axis relatively (never to an absolute target it
//! cannot know), each step bounded by the width of its soft limits, and leaves it flagged.

use heapless::String;
use optalign_protocol::auth::Nonce;
use optalign_protocol::error_reply;
use optalign_protocol::limits::KEY_LEN;
use optalign_protocol::seal::{Direction, Opener, Sealer};
use optalign_protocol::{
    Access, AxisConfig, AxisValue, Capabilities, Command, ErrorCode, ErrorReply, Faults,
    FrameError, Identity, MAX_AXES, MoveOutcome, Notification, PROTOCOL_VERSION, PeerMessage,
    REFUSED_SINCE, RefusalDetail, Reply, Request, RequestId,
};

use crate::config::validate;
use crate::controller::Controller;
use crate::crypto::{Done, Outcome, Work};
use crate::motion::{AxisPlan, Move};
use crate::nonce::NonceError;
use crate::path::plan_path;
use crate::record::WifiCredentials;
use crate::replay::ReplyCache;
use crate::session::{LinkKind, RngSource, Session};
use crate::storage::Storage;

/// What a request comes to before its cryptography.
enum Step {
    Reply(Reply),
    Work(Work),
}

/// A refusal: a plain error, or one with its detail ([`Reply::Refused`]).
enum Denied {
    Plain(ErrorReply),
    Detailed(ErrorReply, RefusalDetail),
}

impl From<ErrorReply> for Denied {
    fn from(error: ErrorReply) -> Self {
        Self::Plain(error)
    }
}

impl Denied {
    fn into_reply(self) -> Reply {
        match self {
            Self::Plain(error) => Reply::Error(error),
            Self::Detailed(error, detail) => Reply::Refused { error, detail },
        }
    }
}

impl<S: Storage> Controller<S> {
    /// Handles one request; `out` receives its reply (and nothing else). Notifications the
    /// request causes are delivered by the next [`poll`](Self::poll). The same as
    /// [`begin`](Self::begin), [`Work::run`] and [`finish`](Self::finish) in a row.
    pub fn handle(
        &mut self,
        session: &mut Session,
        request: &Request,
        now_us: u64,
        rng: &mut dyn RngSource,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        if let Some(work) = self.begin(session, request, now_us, out) {
            let done = work.run(rng);
            self.finish(session, request, done, now_us, out);
        }
    }

    /// Handles one request up to its cryptography: `out` receives the reply, or the
    /// [`Work`] is handed back, to be run (outside the embedder's lock on the controller)
    /// and then given to [`finish`](Self::finish) with the same session and request.
    pub fn begin(
        &mut self,
        session: &mut Session,
        request: &Request,
        now_us: u64,
        out: &mut dyn FnMut(PeerMessage),
    ) -> Option<Work> {
        let now = self.observe(now_us);
        let reply = match self.dispatch(session, request, now) {
            Ok(Step::Work(work)) => return Some(work),
            Ok(Step::Reply(reply)) => reply,
            Err(denied) => denied.into_reply(),
        };
        out(PeerMessage::Reply {
            id: request.id,
            reply,
        });
        None
    }

    /// Answers the request [`begin`](Self::begin) handed back work for, with what the work
    /// found; `out` receives the reply.
    pub fn finish(
        &mut self,
        session: &mut Session,
        request: &Request,
        done: Done,
        now_us: u64,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        let now = self.observe(now_us);
        let reply = match done.0 {
            Outcome::Challenge { id, nonce } => {
                session.nonce = Some((id, nonce));
                Ok(Reply::Challenge { nonce })
            }
            Outcome::Response { epoch, channel } => {
                self.authenticated(session, epoch, channel, now)
            }
        };
        out(PeerMessage::Reply {
            id: request.id,
            reply: reply.unwrap_or_else(Reply::Error),
        });
    }

    /// Reports a frame that could not be read, or that the session's seal check refused
    /// (counted in `Status`); nothing is executed.
    pub fn link_error(&mut self, error: FrameError, out: &mut dyn FnMut(PeerMessage)) {
        if error.is_seal_failure() {
            self.rejected_frames = self.rejected_frames.saturating_add(1);
        }
        out(PeerMessage::LinkError(ErrorReply::new(
            error.code(),
            format_args!("{error}"),
        )));
    }

    fn dispatch(
        &mut self,
        session: &mut Session,
        request: &Request,
        now: u64,
    ) -> Result<Step, Denied> {
        let command = &request.command;
        if !session.handshaken && !matches!(command, Command::Hello { .. }) {
            return Err(error_reply!(
                ErrorCode::HANDSHAKE_REQUIRED,
                "send Hello {{ protocol_version: {PROTOCOL_VERSION} }} first"
            )
            .into());
        }
        if session.refuses_as_stop_only(command) {
            return Err(error_reply!(
                ErrorCode::BUSY,
                "no network slot is free for this connection: only Hello and EmergencyStop here"
            )
            .into());
        }
        self.check_access(session, command)?;
        if !ReplyCache::applies_to(command) {
            // Never remembered: runs every time it arrives (stops, reads, the handshake,
            // authentication).
            self.admit(session, command)?;
            return self.execute(session, request.id, command, now);
        }
        let fingerprint = ReplyCache::fingerprint(command);
        if let Some(reply) = self.replies.lookup(request.id, fingerprint) {
            return Ok(Step::Reply(reply));
        }
        // Not remembered: a request refused as busy may run once control is free.
        self.admit(session, command)?;
        let reply = match self.execute(session, request.id, command, now) {
            // Authentication only, which is never remembered.
            Ok(Step::Work(work)) => return Ok(Step::Work(work)),
            Ok(Step::Reply(reply)) => reply,
            Err(denied) => denied.into_reply(),
        };
        self.replies.remember(request.id, fingerprint, &reply);
        Ok(Step::Reply(reply))
    }

    fn check_access(&self, session: &Session, command: &Command) -> Result<(), ErrorReply> {
        match (command.access(), session.link()) {
            (Access::Open, _) | (_, LinkKind::Serial) => Ok(()),
            (Access::SerialOnly, LinkKind::Network) => Err(error_reply!(
                ErrorCode::SERIAL_ONLY,
                "{} is accepted on the USB serial link only",
                command.name()
            )),
            (Access::Control, LinkKind::Network) if self.key.is_none() => Err(no_key()),
            (Access::Control, LinkKind::Network) if !self.is_authenticated(session) => {
                Err(error_reply!(
                    ErrorCode::UNAUTHORIZED,
                    "{} needs an authenticated session: AuthChallenge, then AuthResponse",
                    command.name()
                ))
            }
            (Access::Control, LinkKind::Network) => Ok(()),
        }
    }

    fn execute(
        &mut self,
        session: &mut Session,
        id: RequestId,
        command: &Command,
        now: u64,
    ) -> Result<Step, Denied> {
        let reply = match command {
            Command::Hello { protocol_version } => self.hello(session, *protocol_version)?,
            Command::AuthChallenge => return self.challenge(session, id, now),
            Command::AuthResponse { tag, client_nonce } => {
                return self.respond(session, tag, client_nonce, now);
            }
            Command::Status => Reply::Status(self.status(session, now)),
            Command::MoveTo { targets } => self.start_move(id, targets, Motion::Absolute, now)?,
            Command::MoveBy { deltas } => self.start_move(id, deltas, Motion::Relative, now)?,
            Command::RecoveryMoveBy { deltas } => {
                self.start_move(id, deltas, Motion::Recovery, now)?
            }
            Command::Stop => {
                self.stop_motion(now);
                Reply::Ok
            }
            Command::EmergencyStop => {
                self.emergency_stop();
                Reply::Ok
            }
            Command::SetPosition { axis, position } => self.set_position(*axis, *position)?,
            Command::GetConfig { axis } => {
                self.axis_index(*axis, false)?;
                let config = self.axes.get(usize::from(*axis)).map(|a| a.config);
                config
                    .map(Reply::Config)
                    .ok_or_else(|| internal("axis vanished"))?
            }
            Command::SetConfig { axis, config } => self.set_config(*axis, config)?,
            Command::SaveConfig => {
                self.idle_for_saving(command)?;
                for axis in self.axes.iter_mut() {
                    axis.saved = axis.config;
                }
                self.save("configuration")?
            }
            Command::ProvisionWifi { ssid, passphrase } => {
                self.idle_for_saving(command)?;
                self.wifi = Some(WifiCredentials {
                    ssid: ssid.clone(),
                    passphrase: passphrase.clone(),
                });
                self.save("Wi-Fi credentials")?
            }
            Command::SetKey { key } => {
                self.idle_for_saving(command)?;
                self.key = Some(*key);
                self.key_epoch = self.key_epoch.wrapping_add(1);
                self.save("access key")?
            }
            Command::ClearEmergency => {
                self.clear_emergency();
                Reply::Ok
            }
            Command::MoveResult { request } => Reply::MoveResult(self.moves.lookup(*request)),
        };
        Ok(Step::Reply(reply))
    }

    fn hello(&self, session: &mut Session, version: u16) -> Result<Reply, Denied> {
        if version != PROTOCOL_VERSION {
            session.handshaken = false;
            let error = error_reply!(
                ErrorCode::VERSION_MISMATCH,
                "peer speaks protocol {PROTOCOL_VERSION}, client sent {version}"
            );
            // A client older than `Refused` gets the error it can decode.
            return Err(if version >= REFUSED_SINCE {
                Denied::Detailed(error, RefusalDetail::ProtocolVersion(PROTOCOL_VERSION))
            } else {
                Denied::Plain(error)
            });
        }
        session.handshaken = true;
        Ok(Reply::Hello(Identity {
            protocol_version: PROTOCOL_VERSION,
            firmware_version: truncated(self.info.firmware_version),
            board: truncated(self.info.board),
            board_id: self.info.board_id,
            axes: u8::try_from(self.axes.len()).unwrap_or(u8::MAX),
            capabilities: Capabilities(self.info.capabilities),
            boot_nonce: self.boot_nonce,
        }))
    }

    /// A fresh nonce (made by the [`Work`] handed back), except for a repeat of the request
    /// that drew the outstanding one (a retransmission or a duplicated frame), which gets
    /// that same nonce: otherwise the client would answer the first nonce while the
    /// controller expects the second.
    fn challenge(
        &mut self,
        session: &mut Session,
        id: RequestId,
        now: u64,
    ) -> Result<Step, Denied> {
        if self.key.is_none() {
            return Err(no_key().into());
        }
        self.check_backoff(now)?;
        if let Some((drawn_for, nonce)) = session.nonce
            && drawn_for == id
        {
            return Ok(Step::Reply(Reply::Challenge { nonce }));
        }
        self.count_boot().map_err(|error| {
            error_reply!(
                ErrorCode::STORAGE,
                "no challenge before the boot counter is saved: {}",
                error.describe()
            )
        })?;
        let draw = self.nonces.reserve().map_err(|error| match error {
            NonceError::BootNotCounted => error_reply!(
                ErrorCode::STORAGE,
                "no challenge before the boot counter is saved"
            ),
            NonceError::Exhausted => error_reply!(
                ErrorCode::STORAGE,
                "every challenge nonce of this boot is used: reboot the board"
            ),
        })?;
        Ok(Step::Work(Work::challenge(id, draw)))
    }

    /// Takes a response to the outstanding challenge; the [`Work`] handed back checks it.
    fn respond(
        &mut self,
        session: &mut Session,
        tag: &[u8; KEY_LEN],
        client_nonce: &Nonce,
        now: u64,
    ) -> Result<Step, Denied> {
        let Some(key) = self.key else {
            return Err(no_key().into());
        };
        // A nonce answers one response, right or wrong (or refused for the backoff).
        let Some((_, nonce)) = session.nonce.take() else {
            return Err(error_reply!(
                ErrorCode::AUTH_FAILED,
                "no challenge outstanding: send AuthChallenge first"
            )
            .into());
        };
        self.check_backoff(now)?;
        Ok(Step::Work(Work::response(
            key,
            self.key_epoch,
            nonce,
            *client_nonce,
            *tag,
        )))
    }

    /// Applies the check of a response against the key of generation `epoch`: on success
    /// the session's frames are sealed from here on, under `channel`, the key derived from
    /// both nonces; a failure is counted and closes authentication for a while
    /// ([`crate::backoff`]).
    fn authenticated(
        &mut self,
        session: &mut Session,
        epoch: u32,
        channel: Option<[u8; KEY_LEN]>,
        now: u64,
    ) -> Result<Reply, ErrorReply> {
        if self.key.is_none() || epoch != self.key_epoch {
            // Checked against a key replaced meanwhile (over the serial link).
            session.authenticated = None;
            return Err(error_reply!(
                ErrorCode::AUTH_FAILED,
                "the access key changed while the response was checked: authenticate again"
            ));
        }
        match channel {
            Some(channel) => {
                self.auth_backoff.succeeded();
                session.authenticated = Some(epoch);
                session
                    .inbound()
                    .install(Opener::new(channel, Direction::ToController), true);
                session.sealer = Some(Sealer::new(channel, Direction::ToHost));
                Ok(Reply::Ok)
            }
            None => {
                self.auth_backoff.failed(now);
                session.authenticated = None;
                Err(error_reply!(
                    ErrorCode::AUTH_FAILED,
                    "challenge response does not verify (wrong key?)"
                ))
            }
        }
    }

    /// Refuses an authentication attempt while the backoff after failures runs, saying
    /// how long it has to wait.
    fn check_backoff(&self, now: u64) -> Result<(), Denied> {
        match self.auth_backoff.wait_us(now) {
            Some(wait_us) => {
                let wait_ms = wait_us.div_ceil(1000);
                Err(Denied::Detailed(
                    error_reply!(
                        ErrorCode::AUTH_BACKOFF,
                        "authentication failed just before: try again in {wait_ms} ms"
                    ),
                    RefusalDetail::RetryAfterMs(u32::try_from(wait_ms).unwrap_or(u32::MAX)),
                ))
            }
            None => Ok(()),
        }
    }

    /// Checks that `axis` exists (and, when `idle`, takes no part in any move).
    fn axis_index(&self, axis: u8, idle: bool) -> Result<usize, ErrorReply> {
        let index = usize::from(axis);
        if index >= self.axes.len() {
            return Err(unknown_axis(axis, self.axes.len()));
        }
        if idle && self.axis_busy(axis) {
            return Err(error_reply!(
                ErrorCode::BUSY,
                "axis {axis} is moving: Stop it or wait for MoveFinished"
            ));
        }
        Ok(index)
    }

    fn start_move(
        &mut self,
        id: RequestId,
        values: &[AxisValue],
        motion: Motion,
        now: u64,
    ) -> Result<Reply, ErrorReply> {
        if self.emergency {
            return Err(error_reply!(
                ErrorCode::EMERGENCY_STOPPED,
                "motion is latched off by an emergency stop: the controlling client must send \
                 ClearEmergency first"
            ));
        }
        // Where the running motion would come to rest if told to stop now.
        let mut braking = self.active.clone();
        if let Some(mv) = braking.as_mut() {
            mv.stop(now);
        }
        let rest = self.rest_state(braking.as_ref());
        let mut plans: heapless::Vec<AxisPlan, MAX_AXES> = heapless::Vec::new();
        for value in values {
            let index = self.axis_index(value.axis, false)?;
            if plans.iter().any(|p| p.axis == value.axis) {
                return Err(error_reply!(
                    ErrorCode::MALFORMED,
                    "axis {} is listed twice",
                    value.axis
                ));
            }
            let (Some(axis), Some(rest)) = (self.axes.get(index), rest.get(index)) else {
                return Err(internal("axis vanished"));
            };
            let lost = axis.faults.has(Faults::POSITION_LOST);
            if lost && motion != Motion::Recovery {
                return Err(error_reply!(
                    ErrorCode::AXIS_FAULT,
                    "axis {}: position lost: declare it with SetPosition (RecoveryMoveBy moves it \
                     meanwhile)",
                    value.axis
                ));
            }
            let limits = axis.config.limits;
            let target = match motion {
                Motion::Absolute => i64::from(value.steps),
                Motion::Relative | Motion::Recovery => {
                    i64::from(rest.position) + i64::from(value.steps)
                }
            };
            let mut config = axis.config;
            let target = if lost {
                // The position the limits bound is unknown: bound the step instead, and
                // let the path's overshoot go wherever the counter goes.
                let width = i64::from(limits.max) - i64::from(limits.min);
                let target = i32::try_from(target)
                    .ok()
                    .filter(|_| i64::from(value.steps).abs() <= width)
                    .ok_or_else(|| {
                        error_reply!(
                            ErrorCode::OUT_OF_LIMITS,
                            "axis {}: position lost, so a recovery move may go at most the width \
                             of its soft limits ({width} steps), not {}",
                            value.axis,
                            value.steps
                        )
                    })?;
                config.limits.min = limits.min.min(target);
                config.limits.max = limits.max.max(target);
                target
            } else {
                i32::try_from(target)
                    .ok()
                    .filter(|&t| limits.contains(t))
                    .ok_or_else(|| {
                        error_reply!(
                            ErrorCode::OUT_OF_LIMITS,
                            "axis {}: target {target} outside soft limits {}..={}",
                            value.axis,
                            limits.min,
                            limits.max
                        )
                    })?
            };
            let plan = AxisPlan {
                axis: value.axis,
                target,
                path: plan_path(rest.gear, rest.position, target, &config),
                max_speed: axis.config.max_speed,
                acceleration: axis.config.acceleration,
            };
            plans.push(plan).map_err(|_| internal("too many axes"))?;
        }

        // Accepted: replace whatever was running or waiting.
        if let Some(waiting) = self.pending.take() {
            let finished = self.finish_move(waiting.request(), MoveOutcome::Stopped);
            self.queue(finished);
        }
        self.moves.started(id);
        self.active = braking;
        // (A move that already ran out but was not yet polled ends in the past.)
        let start = self.active.as_ref().map_or(now, Move::end_us).max(now);
        let planned = Move::plan(id, start, &plans);
        let duration_us = planned.end_us().saturating_sub(now);
        if self.active.is_some() {
            self.pending = Some(planned);
        } else {
            self.active = Some(planned);
        }
        Ok(Reply::MoveStarted {
            duration_ms: u32::try_from(duration_us.div_ceil(1000)).unwrap_or(u32::MAX),
        })
    }

    fn stop_motion(&mut self, now: u64) {
        if let Some(waiting) = self.pending.take() {
            let finished = self.finish_move(waiting.request(), MoveOutcome::Stopped);
            self.queue(finished);
        }
        if let Some(mv) = self.active.as_mut() {
            mv.stop(now);
        }
    }

    /// Stops every axis where it is, releases the coils (at the next poll, which is due at
    /// once) and latches motion off until [`Command::ClearEmergency`].
    fn emergency_stop(&mut self) {
        self.emergency = true;
        if let Some(mv) = self.active.take() {
            for index in mv.stepping_axes() {
                if let Some(axis) = self.axes.get_mut(usize::from(index)) {
                    axis.faults.0 |= Faults::EMERGENCY_STOP;
                    let faults = axis.faults;
                    self.queue(Notification::Fault {
                        axis: index,
                        faults,
                    });
                }
            }
            let finished = self.finish_move(mv.request(), MoveOutcome::EmergencyStopped);
            self.queue(finished);
        }
        if let Some(waiting) = self.pending.take() {
            let finished = self.finish_move(waiting.request(), MoveOutcome::EmergencyStopped);
            self.queue(finished);
        }
        for axis in self.axes.iter_mut().filter(|a| a.powered) {
            axis.cut_pending = true;
            axis.power_down_at = None;
        }
        self.persist_soon();
    }

    /// Releases the emergency latch; the coils stay off until the next move.
    fn clear_emergency(&mut self) {
        self.emergency = false;
        for axis in self.axes.iter_mut() {
            axis.faults.0 &= !Faults::EMERGENCY_STOP;
        }
    }

    fn set_position(&mut self, axis: u8, position: i32) -> Result<Reply, ErrorReply> {
        let index = self.axis_index(axis, true)?;
        let state = self
            .axes
            .get_mut(index)
            .ok_or_else(|| internal("axis vanished"))?;
        let limits = state.config.limits;
        if !limits.contains(position) {
            return Err(error_reply!(
                ErrorCode::OUT_OF_LIMITS,
                "axis {axis}: position {position} outside soft limits {}..={}",
                limits.min,
                limits.max
            ));
        }
        state.position = position;
        state.faults.0 &= !Faults::POSITION_LOST;
        self.save("position")
    }

    fn set_config(&mut self, axis: u8, config: &AxisConfig) -> Result<Reply, ErrorReply> {
        let index = self.axis_index(axis, true)?;
        validate(axis, config, Capabilities(self.info.capabilities))?;
        self.axes
            .get_mut(index)
            .ok_or_else(|| internal("axis vanished"))?
            .set_config(*config);
        Ok(Reply::Ok)
    }

    /// Refuses a command whose answer waits for a flash write while anything moves (a
    /// board does not write flash then); nothing has changed when it is refused.
    fn idle_for_saving(&self, command: &Command) -> Result<(), ErrorReply> {
        if self.is_moving() {
            return Err(error_reply!(
                ErrorCode::BUSY,
                "{} writes flash only while every axis is idle: send it after MoveFinished",
                command.name()
            ));
        }
        Ok(())
    }

    /// Writes the record and, when no axis moves, makes it durable and reads it back
    /// before answering (while axes move, the write waits for them: `Status` shows it
    /// unsaved). `what` names what was changed: it stays in force even if the write fails.
    fn save(&mut self, what: &str) -> Result<Reply, ErrorReply> {
        let moving = self.is_moving();
        self.persist()
            .and_then(|()| if moving { Ok(()) } else { self.commit() })
            .map(|()| Reply::Ok)
            .map_err(|error| {
                error_reply!(
                    ErrorCode::STORAGE,
                    "{what} applied but not saved: {}",
                    error.describe()
                )
            })
    }
}

/// How a move's values are read.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Motion {
    /// Absolute targets (`MoveTo`).
    Absolute,
    /// Deltas from the current positions (`MoveBy`).
    Relative,
    /// Deltas, also on axes whose position is lost (`RecoveryMoveBy`).
    Recovery,
}

fn unknown_axis(axis: u8, axes: usize) -> ErrorReply {
    error_reply!(
        ErrorCode::UNKNOWN_AXIS,
        "axis {axis} does not exist (this peer has {axes} axes)"
    )
}

fn no_key() -> ErrorReply {
    error_reply!(
        ErrorCode::NO_KEY,
        "no key: provision one over USB serial with `optalign provision --serial PATH --key ...`"
    )
}

fn internal(what: &str) -> ErrorReply {
    error_reply!(ErrorCode::INTERNAL, "internal: {what}")
}

/// `text` cut to what fits.
fn truncated<const N: usize>(text: &str) -> String<N> {
    let mut out = String::new();
    for c in text.chars() {
        if out.push(c).is_err() {
            break;
        }
    }
    out
}
