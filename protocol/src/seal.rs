//! Per-frame authentication of an authenticated network session.
//!
//! Once the challenge-response succeeded, both sides hold a session key
//! ([`crate::auth::session_key`]). From then on every frame, in both directions, carries a
//! *seal* after its message: a 64-bit counter, one more than the previous frame's in that
//! direction, and the first [`TAG_LEN`] bytes of
//! `HMAC-SHA256(session key, CONTEXT || direction || counter || message bytes)`.
//!
//! A receiver drops a frame whose tag does not verify or whose counter is not above the last
//! one it accepted: a forged or altered frame, a replay within the session, or a frame of
//! another session (another key) never reaches the dispatcher, nor even the message
//! decoder: the seal is the payload's last [`SEAL_LEN`] bytes and is verified before the
//! message is parsed ([`Inbound::accept`]). Frames are authenticated, not
//! encrypted: whoever shares the network can read them.

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use crate::auth::SessionKey;
use crate::frame::FrameError;

/// Bytes of the truncated HMAC in a seal.
pub const TAG_LEN: usize = 16;

/// Bytes of the counter in a seal.
pub const COUNTER_LEN: usize = 8;

/// Bytes a seal adds to a frame's payload.
pub const SEAL_LEN: usize = COUNTER_LEN + TAG_LEN;

/// Domain separation for frame tags.
const CONTEXT: &[u8] = b"optalign-frame-v1";

/// Which way a frame travels; it enters the tag, so a frame cannot be reflected back.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Direction {
    /// From the host (client) to the controller.
    ToController,
    /// From the controller to the host.
    ToHost,
}

impl Direction {
    fn byte(self) -> u8 {
        match self {
            Self::ToController => 0x01,
            Self::ToHost => 0x02,
        }
    }
}

/// The trailer that authenticates one frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Seal {
    pub counter: u64,
    pub tag: [u8; TAG_LEN],
}

impl Seal {
    /// The seal as it follows the message on the wire: counter (little endian), then tag.
    pub fn to_bytes(&self) -> [u8; SEAL_LEN] {
        let mut bytes = [0u8; SEAL_LEN];
        let (counter, tag) = bytes.split_at_mut(COUNTER_LEN);
        counter.copy_from_slice(&self.counter.to_le_bytes());
        tag.copy_from_slice(&self.tag);
        bytes
    }

    /// Reads a seal from exactly [`SEAL_LEN`] bytes.
    pub fn from_bytes(bytes: &[u8]) -> Option<Self> {
        if bytes.len() != SEAL_LEN {
            return None;
        }
        let (counter, tag) = bytes.split_at(COUNTER_LEN);
        Some(Self {
            counter: u64::from_le_bytes(counter.try_into().ok()?),
            tag: tag.try_into().ok()?,
        })
    }
}

/// Seals the frames one side sends.
#[derive(Clone, Debug)]
pub struct Sealer {
    key: SessionKey,
    direction: Direction,
    next: u64,
}

impl Sealer {
    pub fn new(key: SessionKey, direction: Direction) -> Self {
        Self {
            key,
            direction,
            next: 1,
        }
    }

    /// The seal of the next frame, whose message encodes to `message`.
    pub fn seal(&mut self, message: &[u8]) -> Seal {
        let counter = self.next;
        self.next = self.next.saturating_add(1);
        let tag = tag(&self.key, self.direction, counter, message)
            .finalize()
            .into_bytes();
        let mut truncated = [0u8; TAG_LEN];
        truncated.copy_from_slice(&tag[..TAG_LEN]);
        Seal {
            counter,
            tag: truncated,
        }
    }
}

/// Checks the seals of the frames one side receives.
#[derive(Clone, Debug)]
pub struct Opener {
    key: SessionKey,
    direction: Direction,
    /// The lowest counter still acceptable.
    next: u64,
}

impl Opener {
    pub fn new(key: SessionKey, direction: Direction) -> Self {
        Self {
            key,
            direction,
            next: 1,
        }
    }

    /// Accepts a frame whose tag verifies (in constant time) and whose counter is above
    /// every one accepted before.
    pub fn open(&mut self, message: &[u8], seal: &Seal) -> Result<(), FrameError> {
        tag(&self.key, self.direction, seal.counter, message)
            .verify_truncated_left(&seal.tag)
            .map_err(|_| FrameError::BadSeal)?;
        if seal.counter < self.next {
            return Err(FrameError::Replayed);
        }
        self.next = seal.counter.saturating_add(1);
        Ok(())
    }
}

/// What a receiver accepts: plain frames until its session is authenticated, and from then
/// on only frames with a valid seal.
#[derive(Clone, Debug, Default)]
pub struct Inbound {
    opener: Option<Opener>,
    sealed_only: bool,
}

impl Inbound {
    /// Accepts plain frames only (no session key yet).
    pub const fn plain() -> Self {
        Self {
            opener: None,
            sealed_only: false,
        }
    }

    /// Starts checking seals with `opener`. With `sealed_only`, plain frames are refused at
    /// once (the controller, once the client authenticated); without, they are refused
    /// from the first valid seal on (the client, which cannot know which of the frames in
    /// flight the controller sent before it switched).
    pub fn install(&mut self, opener: Opener, sealed_only: bool) {
        self.opener = Some(opener);
        self.sealed_only = sealed_only;
    }

    /// Whether a session key is installed.
    pub fn has_key(&self) -> bool {
        self.opener.is_some()
    }

    /// Whether only sealed frames are accepted now.
    pub fn is_sealed(&self) -> bool {
        self.sealed_only
    }

    /// Accepts or refuses a frame's `payload` before any of it is decoded, and returns the
    /// message bytes to decode.
    ///
    /// With a session key, the last [`SEAL_LEN`] bytes are taken for a seal and verified
    /// over the bytes before them first: on a sealed session nothing the key did not
    /// authenticate reaches the message decoder. A receiver that still accepts plain frames
    /// (a client just after authenticating) takes a payload whose seal does not verify as
    /// a plain message ([`Accepted::Plain`]). Without a session key every payload is plain.
    pub fn accept<'a>(&mut self, payload: &'a [u8]) -> Result<Accepted<'a>, FrameError> {
        let Some(opener) = self.opener.as_mut() else {
            return Ok(Accepted::Plain(payload));
        };
        let Some(split) = payload.len().checked_sub(SEAL_LEN).filter(|&at| at > 0) else {
            return if self.sealed_only {
                Err(FrameError::Unsealed)
            } else {
                Ok(Accepted::Plain(payload))
            };
        };
        let (message, seal) = payload.split_at(split);
        let seal = Seal::from_bytes(seal).ok_or(FrameError::BadSeal)?;
        match opener.open(message, &seal) {
            Ok(()) => {
                self.sealed_only = true;
                Ok(Accepted::Sealed(message))
            }
            Err(FrameError::BadSeal) if !self.sealed_only => Ok(Accepted::Plain(payload)),
            Err(error) => Err(error),
        }
    }
}

/// A frame's message bytes, once [`Inbound::accept`] let the frame through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Accepted<'a> {
    /// The message before a seal that verified.
    Sealed(&'a [u8]),
    /// A payload with no seal to verify: one message, or a sealed frame of no session this
    /// receiver knows (which then does not decode as one message).
    Plain(&'a [u8]),
}

fn tag(key: &SessionKey, direction: Direction, counter: u64, message: &[u8]) -> Hmac<Sha256> {
    let mut mac =
        <Hmac<Sha256> as KeyInit>::new_from_slice(key).expect("HMAC accepts keys of any length");
    mac.update(CONTEXT);
    mac.update(&[direction.byte()]);
    mac.update(&counter.to_le_bytes());
    mac.update(message);
    mac
}
