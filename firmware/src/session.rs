//! One connection's state: link kind, handshake, authentication and the control claim.

use optalign_protocol::RequestId;
use optalign_protocol::limits::NONCE_LEN;

/// The kind of link a session runs on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkKind {
    /// USB serial: trusted, because it needs physical access.
    Serial,
    /// TCP over Wi-Fi: motion needs an authenticated session.
    Network,
}

/// Per-connection state; the embedder keeps one per open connection and passes it to
/// [`Controller::handle`](crate::Controller::handle).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Session {
    link: LinkKind,
    pub(crate) handshaken: bool,
    /// The key generation this session authenticated against (a new key revokes it).
    pub(crate) authenticated: Option<u32>,
    /// The outstanding challenge and the request that asked for it; used up by the next
    /// response.
    pub(crate) nonce: Option<(RequestId, [u8; NONCE_LEN])>,
    /// The control claim this session was given (see [`crate::Controller::end_session`]).
    pub(crate) claim: Option<u32>,
}

impl Session {
    pub fn new(link: LinkKind) -> Self {
        Self {
            link,
            handshaken: false,
            authenticated: None,
            nonce: None,
            claim: None,
        }
    }

    pub fn link(&self) -> LinkKind {
        self.link
    }

    /// Whether the `Hello` handshake succeeded.
    pub fn is_handshaken(&self) -> bool {
        self.handshaken
    }
}

/// A source of unpredictable bytes (the RP2040's ring oscillator, or the host's RNG).
pub trait RngSource {
    fn fill(&mut self, buf: &mut [u8]);
}
