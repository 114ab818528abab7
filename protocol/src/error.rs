//! Error replies: stable numeric codes plus a short human-readable reason.

use core::fmt::{self, Write};

use heapless::String;
use serde::{Deserialize, Serialize};

use crate::limits::REASON_LEN;

/// A stable numeric error code. Codes are never renumbered; new ones are only added, so a
/// host can always name a code even when it comes from a newer firmware.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct ErrorCode(pub u16);

impl ErrorCode {
    /// The frame's COBS stuffing was invalid.
    pub const BAD_FRAME: Self = Self(1);
    /// The frame's CRC did not match its contents.
    pub const BAD_CRC: Self = Self(2);
    /// The frame exceeded the maximum frame size.
    pub const FRAME_TOO_LARGE: Self = Self(3);
    /// The frame was intact but did not decode as a message.
    pub const MALFORMED: Self = Self(4);
    /// On an authenticated session: the frame's MAC did not verify, its counter was not
    /// above the last one (a replay), or it carried no MAC. It was dropped.
    pub const BAD_SEAL: Self = Self(5);
    /// The two sides speak different protocol versions.
    pub const VERSION_MISMATCH: Self = Self(10);
    /// A request arrived before the `Hello` handshake.
    pub const HANDSHAKE_REQUIRED: Self = Self(11);
    /// The request needs an authenticated session (TCP) and this one is not.
    pub const UNAUTHORIZED: Self = Self(20);
    /// Motion over TCP is refused because no key has been provisioned yet.
    pub const NO_KEY: Self = Self(21);
    /// The challenge response did not verify.
    pub const AUTH_FAILED: Self = Self(22);
    /// The request is only accepted on the serial link.
    pub const SERIAL_ONLY: Self = Self(23);
    /// Authentications failed just before: the next one is accepted after a delay.
    pub const AUTH_BACKOFF: Self = Self(24);
    /// Another client controls this peer.
    pub const BUSY: Self = Self(30);
    /// The request named an axis the peer does not have.
    pub const UNKNOWN_AXIS: Self = Self(40);
    /// A target lies outside the axis's soft limits.
    pub const OUT_OF_LIMITS: Self = Self(41);
    /// A configuration value is out of range.
    pub const INVALID_CONFIG: Self = Self(42);
    /// Motion is latched off by an emergency stop until `ClearEmergency`.
    pub const EMERGENCY_STOPPED: Self = Self(43);
    /// The axis is in a fault state (its position is lost: `SetPosition` declares it).
    pub const AXIS_FAULT: Self = Self(44);
    /// Persistent storage failed.
    pub const STORAGE: Self = Self(50);
    /// The peer hit an internal limit (a bug if it ever appears).
    pub const INTERNAL: Self = Self(60);

    /// A short stable name for the code, or `"unknown"` for codes newer than this build.
    pub fn name(self) -> &'static str {
        match self {
            Self::BAD_FRAME => "bad-frame",
            Self::BAD_CRC => "bad-crc",
            Self::FRAME_TOO_LARGE => "frame-too-large",
            Self::MALFORMED => "malformed",
            Self::BAD_SEAL => "bad-seal",
            Self::VERSION_MISMATCH => "version-mismatch",
            Self::HANDSHAKE_REQUIRED => "handshake-required",
            Self::UNAUTHORIZED => "unauthorized",
            Self::NO_KEY => "no-key",
            Self::AUTH_FAILED => "auth-failed",
            Self::SERIAL_ONLY => "serial-only",
            Self::AUTH_BACKOFF => "auth-backoff",
            Self::BUSY => "busy",
            Self::UNKNOWN_AXIS => "unknown-axis",
            Self::OUT_OF_LIMITS => "out-of-limits",
            Self::INVALID_CONFIG => "invalid-config",
            Self::EMERGENCY_STOPPED => "emergency-stopped",
            Self::AXIS_FAULT => "axis-fault",
            Self::STORAGE => "storage",
            Self::INTERNAL => "internal",
            _ => "unknown",
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} ({})", self.name(), self.0)
    }
}

/// An error answer: the code for programs, the reason for people.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ErrorReply {
    pub code: ErrorCode,
    pub reason: String<REASON_LEN>,
}

impl ErrorReply {
    /// Builds a reply, formatting the reason; an over-long reason is cut at the limit.
    pub fn new(code: ErrorCode, reason: fmt::Arguments<'_>) -> Self {
        let mut text = TruncatingString::default();
        // A truncating writer never fails.
        let _ = text.write_fmt(reason);
        Self {
            code,
            reason: text.0,
        }
    }
}

impl fmt::Display for ErrorReply {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}: {}", self.code, self.reason)
    }
}

/// A `fmt::Write` sink that keeps what fits and silently drops the rest.
#[derive(Default)]
struct TruncatingString(String<REASON_LEN>);

impl Write for TruncatingString {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for c in s.chars() {
            if self.0.push(c).is_err() {
                break;
            }
        }
        Ok(())
    }
}

/// Formats an [`ErrorReply`] in place: `error_reply!(ErrorCode::BUSY, "held by {}", who)`.
#[macro_export]
macro_rules! error_reply {
    ($code:expr, $($arg:tt)*) => {
        $crate::error::ErrorReply::new($code, format_args!($($arg)*))
    };
}
