//! One connection's protocol state: link kind, handshake, authentication, the sealed
//! channel that follows it, the control claim, and whether the connection waits in the
//! lobby beside the network slots (see [`crate::connection`] for when a connection is closed and
//! [`crate::admission`] for who gets a slot).

use optalign_protocol::auth::Nonce;
use optalign_protocol::seal::{Inbound, Sealer};
use optalign_protocol::{Command, RequestId};

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
    /// Waiting in the lobby beside the network slots: nothing but the handshake and
    /// emergency stops.
    stop_only: bool,
}

impl Session {
    pub fn new(link: LinkKind) -> Self {
        Self {
            link,
            handshaken: false,
            authenticated: None,
            nonce: None,
            claim: None,
            inbound: Inbound::plain(),
            sealer: None,
            stop_only: false,
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

    /// Limits this session to the handshake and emergency stops: its connection waits in
    /// the lobby for a network slot.
    pub fn limit_to_stopping(&mut self) {
        self.stop_only = true;
    }

    /// Whether this session may only shake hands and stop.
    pub fn is_stop_only(&self) -> bool {
        self.stop_only
    }

    /// Gives this session full rights (its connection got a slot).
    pub fn lift_stop_only(&mut self) {
        self.stop_only = false;
    }

    /// Whether `command` is refused because this session may only shake hands and stop
    /// (its connection is closed after the refusal).
    pub fn refuses_as_stop_only(&self, command: &Command) -> bool {
        self.stop_only && !matches!(command, Command::Hello { .. } | Command::EmergencyStop)
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

/// A source of unpredictable bytes (a generator seeded from the RP2040's ring oscillator,
/// or the host's RNG).
pub trait RngSource {
    fn fill(&mut self, buf: &mut [u8]);
}
