//! One connection, without I/O: bytes in, frames out, and when it is closed.
//!
//! Every link that serves the protocol (the board's TCP and USB links, the emulator's
//! UART, the simulated peer's sockets and pseudo-terminal) runs the same [`Connection`]:
//! the embedder feeds it the bytes it reads ([`Connection::receive`]), writes what it is
//! given back ([`Connection::encode`]), closes the connection when it says so, and ends it
//! with [`Connection::end`]. The embedder's side is a [`Port`]: its controller and its
//! admission table ([`crate::admission`]).
//!
//! The rules it carries:
//! - frames are decoded against the session (sealed only, once authenticated), and every
//!   frame sent after authentication is sealed, the reply that confirmed it first;
//! - a connection in the lobby (see [`crate::admission`]) may only shake hands and stop:
//!   each well-formed request it sends first asks for a slot ([`Port::promote`]); it is
//!   closed [`Deadlines::stop_only_us`] after it opened, and at once after a request it
//!   may not send;
//! - a network connection that has not authenticated is closed [`Deadlines::idle_us`]
//!   after its last well-formed request (after it opened, for one that never sent any);
//!   serial and authenticated connections never for idleness;
//! - a write the client does not take within [`Deadlines::send_us`] closes the connection
//!   ([`Connection::send_deadline_us`]): a client that sends requests and never reads the
//!   replies cannot hold its connection, nor stall anyone else;
//! - the admission table learns how the connection stands (silent, spoke, authenticated),
//!   which decides who is evicted when the slots are full.

use optalign_protocol::seal::Sealer;
use optalign_protocol::{
    FrameDecoder, FrameError, MAX_FRAME, PeerMessage, Request, encode_frame, encode_sealed_frame,
};

use crate::admission::{Admissions, Standing, Ticket};
use crate::session::{LinkKind, Session};

/// How long connections are given, in µs of the embedder's clock.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Deadlines {
    /// An unauthenticated network connection without a well-formed request.
    pub idle_us: u64,
    /// A connection in the lobby, from when it opened.
    pub stop_only_us: u64,
    /// One write, from when it started.
    pub send_us: u64,
}

impl Deadlines {
    /// What boards and the simulated peer use.
    pub const STANDARD: Self = Self {
        idle_us: 5_000_000,
        stop_only_us: 2_000_000,
        send_us: 2_000_000,
    };
}

impl Default for Deadlines {
    fn default() -> Self {
        Self::STANDARD
    }
}

/// The embedder's side of a connection: its controller, and its admission table.
pub trait Port {
    /// Hands `request` to the controller for `session`; `out` receives the reply.
    fn request(
        &mut self,
        session: &mut Session,
        request: &Request,
        out: &mut dyn FnMut(PeerMessage),
    );
    /// Reports a frame that could not be read or was refused.
    fn link_error(&mut self, error: FrameError, out: &mut dyn FnMut(PeerMessage));
    /// The connection holding `ticket` now stands as `standing`.
    fn standing(&mut self, ticket: Ticket, standing: Standing);
    /// The lobby connection holding `ticket` sent a well-formed request: its slot, if the
    /// admission table gives it one (the embedder closes whoever was evicted for it).
    fn promote(&mut self, ticket: Ticket) -> Option<Ticket>;
    /// The connection ended: end `session` (releasing control) and free `ticket`.
    fn end(&mut self, session: &mut Session, ticket: Ticket);
}

/// What a received byte leads to.
#[derive(Debug, PartialEq)]
pub enum Received {
    /// Nothing to send yet.
    Nothing,
    /// Send this message ([`Connection::encode`]).
    Send(PeerMessage),
    /// Send this message, then close the connection.
    SendAndClose(PeerMessage),
}

/// One open connection.
pub struct Connection {
    session: Session,
    decoder: FrameDecoder,
    sealer: Option<Sealer>,
    ticket: Ticket,
    standing: Standing,
    deadlines: Deadlines,
    opened_us: u64,
    heard_us: u64,
}

impl Connection {
    /// The trusted serial link's connection (USB, UART, a pseudo-terminal), opened at
    /// `now_us` with the standard deadlines.
    pub fn serial(now_us: u64) -> Self {
        Self::open(
            LinkKind::Serial,
            Ticket::Serial,
            now_us,
            Deadlines::STANDARD,
        )
    }

    /// A connection on `link` opened at `now_us` with the place `ticket` (for the serial
    /// link, [`Ticket::Serial`]).
    pub fn open(link: LinkKind, ticket: Ticket, now_us: u64, deadlines: Deadlines) -> Self {
        let mut session = Session::new(link);
        if Admissions::<()>::in_lobby(ticket) {
            session.limit_to_stopping();
        }
        Self {
            session,
            decoder: FrameDecoder::new(),
            sealer: None,
            ticket,
            standing: Standing::Silent,
            deadlines,
            opened_us: now_us,
            heard_us: now_us,
        }
    }

    /// Feeds one byte received at `now_us`; a byte that completes a frame has it handled
    /// by the controller, and its answer comes back to be sent.
    pub fn receive(&mut self, byte: u8, now_us: u64, port: &mut impl Port) -> Received {
        let Some(frame) = self
            .decoder
            .push_checked::<Request>(byte, self.session.inbound())
        else {
            return Received::Nothing;
        };
        let mut answer = None;
        let mut close = false;
        let mut standing = self.standing;
        match frame {
            Ok(request) => {
                self.heard_us = self.heard_us.max(now_us);
                standing = standing.max(Standing::Spoke);
                if self.session.is_stop_only()
                    && let Some(slot) = port.promote(self.ticket)
                {
                    self.ticket = slot;
                    self.session.lift_stop_only();
                    self.opened_us = now_us;
                }
                close = self.session.refuses_as_stop_only(&request.command);
                port.request(&mut self.session, &request, &mut |m| answer = Some(m));
            }
            Err(error) => port.link_error(error, &mut |m| answer = Some(m)),
        }
        if let Some(fresh) = self.session.take_sealer() {
            self.sealer = Some(fresh);
        }
        if self.session.has_authenticated() {
            standing = Standing::Authenticated;
        }
        if standing != self.standing {
            self.standing = standing;
            port.standing(self.ticket, standing);
        }
        match answer {
            Some(message) if close => Received::SendAndClose(message),
            Some(message) => Received::Send(message),
            // A controller without power answers nothing.
            None => Received::Nothing,
        }
    }

    /// Encodes `message` as one frame into `out` (sealed once the session authenticated);
    /// the frame's length.
    pub fn encode(
        &mut self,
        message: &PeerMessage,
        out: &mut [u8; MAX_FRAME],
    ) -> Result<usize, FrameError> {
        match self.sealer.as_mut() {
            Some(sealer) => encode_sealed_frame(message, sealer, out),
            None => encode_frame(message, out),
        }
    }

    /// When the embedder closes this connection (unless something happens first); `None`
    /// while it may stay.
    pub fn close_at_us(&self) -> Option<u64> {
        if self.session.is_stop_only() {
            return Some(self.opened_us.saturating_add(self.deadlines.stop_only_us));
        }
        if self.session.link() == LinkKind::Serial || self.session.has_authenticated() {
            return None;
        }
        Some(self.heard_us.saturating_add(self.deadlines.idle_us))
    }

    /// The latest time a write started at `now_us` may finish; past it the embedder
    /// closes the connection.
    pub fn send_deadline_us(&self, now_us: u64) -> u64 {
        now_us.saturating_add(self.deadlines.send_us)
    }

    /// Ends the connection: its session (releasing control) and its place.
    pub fn end(&mut self, port: &mut impl Port) {
        port.end(&mut self.session, self.ticket);
    }

    /// The protocol state (for tests and in-process use).
    pub fn session(&self) -> &Session {
        &self.session
    }

    pub fn ticket(&self) -> Ticket {
        self.ticket
    }
}
