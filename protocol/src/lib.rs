//! The optalign wire protocol: every message the host and the motor-controller firmware
//! exchange, how they are framed on a byte stream, the version handshake, the
//! challenge-response that guards motion over the network and the per-frame MAC of an
//! authenticated session.
//!
//! One crate, compiled into both the firmware (`no_std`) and the host, so the two sides
//! cannot drift apart. See `docs/protocol.md` for the normative description.
#![no_std]

pub mod auth;
pub mod error;
pub mod frame;
pub mod limits;
pub mod message;
pub mod seal;

pub use error::{ErrorCode, ErrorReply};
pub use frame::{FrameDecoder, FrameError, encode_frame, encode_sealed_frame};
pub use limits::{MAX_AXES, MAX_FRAME, MAX_PAYLOAD, PROTOCOL_VERSION, REFUSED_SINCE};
pub use message::*;
