//! One connection's state: link kind, handshake, authentication, the sealed channel that
//! follows it, the control claim, and when an unauthenticated network connection is closed.
//!
//! Closing idle strangers: a network session that has not authenticated is closed
//! [`UNAUTHENTICATED_IDLE_US`] after its last request, and one on the slot kept for a
//! client that authenticates ([`Session::keep_for_authentication`]) is closed
//! [`RESERVED_SLOT_AUTH_US`] after it opened unless it authenticated by then. The embedder
//! asks [`Session::close_at_us`] and closes the connection when that time passes; serial and
//! authenticated sessions are never closed for idleness.

use optalign_protocol::auth::Nonce;
use optalign_protocol::seal::{Inbound, Sealer};
use optalign_protocol::{Command, RequestId};

/// How long an unauthenticated network session may stay without a request.
pub const UNAUTHENTICATED_IDLE_US: u64 = 5_000_000;

/// How long a session on the reserved slot has to authenticate.
pub const RESERVED_SLOT_AUTH_US: u64 = 5_000_000;

/// The kind of link a session runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkKind {
    /// USB serial: trusted, because it needs physical access. Its frames are never sealed.
    Serial,
    /// TCP over Wi-Fi: motion needs an authenticated session, whose frames are sealed.
    Network,
}

/// Per-connection state; the embedder keeps one per open connection and passes it to
/// [`Controller::handle`](crate::Controller::handle).
#[derive(Clone, Debug)]
pub struct Session {
    link: LinkKind,
    pub(crate) handshaken: bool,
    /// The key generation this session authenticated against (a new key revokes it).
    pub(crate) authenticated: Option<u32>,
    /// The outstanding challenge and the request that asked for it; used up by the next
    /// response.
    pub(crate) nonce: Option<(RequestId, Nonce)>,
    /// The control claim this session was given (see [`crate::Controller::end_session`]).
    pub(crate) claim: Option<u32>,
    /// What this session's incoming frames must carry (seals, once authenticated).
    inbound: Inbound,
    /// The sealer for outgoing frames, from authentication until the embedder takes it.
    pub(crate) sealer: Option<Sealer>,
    /// The slot kept for a client that authenticates: nothing but the handshake,
    /// authentication and emergency stops until it does.
    reserved: bool,
    opened_us: u64,
    heard_us: u64,
}

impl Session {
    pub fn new(link: LinkKind) -> Self {
        Self::opened(link, 0)
    }

    /// A session whose connection opened at `now_us` (the embedder's clock for
    /// [`close_at_us`](Self::close_at_us)).
    pub fn opened(link: LinkKind, now_us: u64) -> Self {
        Self {
            link,
            handshaken: false,
            authenticated: None,
            nonce: None,
            claim: None,
            inbound: Inbound::plain(),
            sealer: None,
            reserved: false,
            opened_us: now_us,
            heard_us: now_us,
        }
    }

    pub fn link(&self) -> LinkKind {
        self.link
    }

    /// Whether the `Hello` handshake succeeded.
    pub fn is_handshaken(&self) -> bool {
        self.handshaken
    }

    /// Whether this session authenticated (under some key).
    pub fn has_authenticated(&self) -> bool {
        self.authenticated.is_some()
    }

    /// Marks this session as holding the last free slot, kept for a client that
    /// authenticates.
    pub fn keep_for_authentication(&mut self) {
        self.reserved = true;
    }

    /// Whether this session holds the reserved slot and has not authenticated.
    pub(crate) fn restricted(&self) -> bool {
        self.reserved && self.authenticated.is_none()
    }

    /// Whether `command` is refused because this session holds the reserved slot and has
    /// not authenticated (an embedder may close the connection after the refusal).
    pub fn refuses_on_reserved_slot(&self, command: &Command) -> bool {
        self.restricted() && !opens_reserved_slot(command)
    }

    /// Notes a request received at `now_us` (the embedder's clock).
    pub fn heard(&mut self, now_us: u64) {
        self.heard_us = self.heard_us.max(now_us);
    }

    /// When the embedder closes this connection unless it authenticates or (off the
    /// reserved slot) sends a request first; `None` for serial and authenticated sessions.
    pub fn close_at_us(&self) -> Option<u64> {
        if self.link == LinkKind::Serial || self.authenticated.is_some() {
            return None;
        }
        let idle = self.heard_us.saturating_add(UNAUTHENTICATED_IDLE_US);
        if self.reserved {
            Some(idle.min(self.opened_us.saturating_add(RESERVED_SLOT_AUTH_US)))
        } else {
            Some(idle)
        }
    }

    /// What incoming frames must carry: the embedder decodes every frame against it
    /// ([`optalign_protocol::FrameDecoder::push_checked`]).
    pub fn inbound(&mut self) -> &mut Inbound {
        &mut self.inbound
    }

    /// The sealer for every frame sent from now on, once, right after the session
    /// authenticated (the reply to `AuthResponse` is the first frame it seals).
    pub fn take_sealer(&mut self) -> Option<Sealer> {
        self.sealer.take()
    }
}

/// What a session on the reserved slot may send before it authenticates.
pub(crate) fn opens_reserved_slot(command: &Command) -> bool {
    matches!(
        command,
        Command::Hello { .. }
            | Command::AuthChallenge
            | Command::AuthResponse { .. }
            | Command::EmergencyStop
    )
}

/// A source of unpredictable bytes (a generator seeded from the RP2040's ring oscillator,
/// or the host's RNG).
pub trait RngSource {
    fn fill(&mut self, buf: &mut [u8]);
}
