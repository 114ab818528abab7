//! Framing of messages on a byte stream (TCP or serial).
//!
//! A frame is `COBS(postcard(message) || CRC-32C(postcard(message)) as little endian)`
//! followed by a single `0x00` delimiter. COBS guarantees the delimiter never appears
//! inside a frame, so a receiver that loses sync (line noise, a torn write, garbage)
//! recovers at the next `0x00`. Empty frames (`0x00 0x00`) are ignored, so a sender may
//! emit a delimiter first to flush a half-received frame at the other end.
//!
//! On an authenticated network session a frame's payload is the message followed by its
//! [`Seal`](crate::seal::Seal) (counter and truncated MAC, see [`crate::seal`]): postcard
//! messages delimit themselves, so what follows the message is the seal.
//! [`encode_sealed_frame`] writes such frames; [`FrameDecoder::push_checked`] and
//! [`FrameDecoder::feed_checked`] read them and check the seal against the receiver's
//! [`Inbound`] before the message is decoded. The plain [`FrameDecoder::push`] and
//! [`FrameDecoder::feed`] accept unsealed frames only.

use core::fmt;

use crc::{CRC_32_ISCSI, Crc, Table};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::ErrorCode;
use crate::limits::{CRC_LEN, MAX_FRAME, MAX_PAYLOAD};
use crate::seal::{Accepted, Inbound, SEAL_LEN, Sealer};

/// CRC-32C. On a host, slice-by-16: a 16 KiB table, several times faster than byte-wise.
/// On a microcontroller (no OS), byte-wise with a 1 KiB table: the table is read on every
/// frame and lives in flash, and slice-by-16's would fill the RP2040's and RP2350's whole
/// 16 KiB XIP cache, evicting the motion code. Cycles per frame of each on the emulator
/// image: docs/results.md, measured with builds that pick another one by
/// `--cfg optalign_crc="bitwise"` (no table) or `"slice16"`.
#[cfg(any(
    all(not(target_os = "none"), not(optalign_crc = "bitwise")),
    optalign_crc = "slice16"
))]
type CrcTable = Table<16>;
#[cfg(all(
    target_os = "none",
    not(optalign_crc = "bitwise"),
    not(optalign_crc = "slice16")
))]
type CrcTable = Table<1>;
#[cfg(optalign_crc = "bitwise")]
type CrcTable = crc::NoTable;
const CRC32C: Crc<u32, CrcTable> = Crc::<u32, CrcTable>::new(&CRC_32_ISCSI);

/// The CRC of a frame's payload, both ways. Kept out of line: one copy of the loop for
/// encoding and decoding, and a symbol the emulator harness can count cycles in.
#[inline(never)]
fn frame_crc(payload: &[u8]) -> u32 {
    CRC32C.checksum(payload)
}

/// Why a frame could not be produced or read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The message does not fit in [`MAX_PAYLOAD`] bytes (encoder side).
    TooLargeToSend,
    /// More than [`MAX_FRAME`] bytes arrived without a delimiter.
    TooLarge,
    /// The COBS stuffing was invalid, or the frame was shorter than its CRC.
    BadStuffing,
    /// The CRC did not match.
    BadCrc,
    /// The frame was intact but is not a valid message.
    Malformed,
    /// The frame's seal did not verify: forged, altered, or of another session.
    BadSeal,
    /// The frame's seal verified but its counter was not above the last one accepted: a
    /// replay.
    Replayed,
    /// A plain frame on a session whose frames must be sealed.
    Unsealed,
    /// A sealed frame on a session that has no session key.
    UnexpectedSeal,
}

impl FrameError {
    /// Whether the frame was refused by the session's seal check (rather than unreadable).
    pub fn is_seal_failure(self) -> bool {
        matches!(
            self,
            Self::BadSeal | Self::Replayed | Self::Unsealed | Self::UnexpectedSeal
        )
    }
}

impl FrameError {
    /// The protocol error code reported to the sender of a bad frame.
    pub fn code(self) -> ErrorCode {
        match self {
            Self::TooLarge | Self::TooLargeToSend => ErrorCode::FRAME_TOO_LARGE,
            Self::BadStuffing => ErrorCode::BAD_FRAME,
            Self::BadCrc => ErrorCode::BAD_CRC,
            Self::Malformed => ErrorCode::MALFORMED,
            Self::BadSeal | Self::Replayed | Self::Unsealed | Self::UnexpectedSeal => {
                ErrorCode::BAD_SEAL
            }
        }
    }
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::TooLargeToSend => "message exceeds the maximum payload size",
            Self::TooLarge => "frame exceeds the maximum frame size",
            Self::BadStuffing => "frame is not valid COBS or is truncated",
            Self::BadCrc => "frame CRC mismatch",
            Self::Malformed => "frame does not decode as a message",
            Self::BadSeal => "frame MAC does not verify for this session (forged or altered)",
            Self::Replayed => "frame counter not above the last one accepted (a replay)",
            Self::Unsealed => "frame carries no MAC but this session is authenticated",
            Self::UnexpectedSeal => "frame carries a MAC but this session has no session key",
        })
    }
}

/// Encodes `message` as one complete frame (delimiter included) into `out`, returning the
/// number of bytes written.
pub fn encode_frame<T: Serialize>(
    message: &T,
    out: &mut [u8; MAX_FRAME],
) -> Result<usize, FrameError> {
    encode(message, None, out)
}

/// Encodes `message` followed by its seal from `sealer` as one complete frame.
pub fn encode_sealed_frame<T: Serialize>(
    message: &T,
    sealer: &mut Sealer,
    out: &mut [u8; MAX_FRAME],
) -> Result<usize, FrameError> {
    encode(message, Some(sealer), out)
}

fn encode<T: Serialize>(
    message: &T,
    sealer: Option<&mut Sealer>,
    out: &mut [u8; MAX_FRAME],
) -> Result<usize, FrameError> {
    let mut raw = [0u8; MAX_PAYLOAD + SEAL_LEN + CRC_LEN];
    let mut len = postcard::to_slice(message, &mut raw[..MAX_PAYLOAD])
        .map_err(|_| FrameError::TooLargeToSend)?
        .len();
    if let Some(sealer) = sealer {
        let seal = sealer.seal(&raw[..len]).to_bytes();
        raw[len..len + SEAL_LEN].copy_from_slice(&seal);
        len += SEAL_LEN;
    }
    let crc = frame_crc(&raw[..len]);
    raw[len..len + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
    let stuffed = cobs::try_encode(&raw[..len + CRC_LEN], &mut out[..MAX_FRAME - 1])
        .map_err(|_| FrameError::TooLargeToSend)?;
    out[stuffed] = 0;
    Ok(stuffed + 1)
}

/// Reassembles frames from a byte stream, one byte at a time, with bounded memory.
///
/// Never panics, whatever the input: every malformed frame yields one error and the
/// decoder continues with the next frame.
pub struct FrameDecoder {
    buf: [u8; MAX_FRAME],
    len: usize,
    overflowed: bool,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl FrameDecoder {
    pub const fn new() -> Self {
        Self {
            buf: [0; MAX_FRAME],
            len: 0,
            overflowed: false,
        }
    }

    /// Discards any partial frame (for example after a reconnect).
    pub fn reset(&mut self) {
        self.len = 0;
        self.overflowed = false;
    }

    /// Whether a frame is partly received.
    pub fn in_frame(&self) -> bool {
        self.len > 0 || self.overflowed
    }

    /// Feeds one byte; returns a message or an error when the byte ends a frame. Only plain
    /// (unsealed) frames are accepted.
    pub fn push<T: DeserializeOwned>(&mut self, byte: u8) -> Option<Result<T, FrameError>> {
        self.push_with(byte, decode_plain)
    }

    /// Like [`push`](Self::push), checking each frame's seal (or its absence) against
    /// `inbound`; a refused frame yields its error and nothing else.
    pub fn push_checked<T: DeserializeOwned>(
        &mut self,
        byte: u8,
        inbound: &mut Inbound,
    ) -> Option<Result<T, FrameError>> {
        self.push_with(byte, |payload| decode_checked(payload, inbound))
    }

    fn push_with<T>(
        &mut self,
        byte: u8,
        decode: impl FnOnce(&[u8]) -> Result<T, FrameError>,
    ) -> Option<Result<T, FrameError>> {
        if byte != 0 {
            if self.len < self.buf.len() {
                self.buf[self.len] = byte;
                self.len += 1;
            } else {
                self.overflowed = true;
            }
            return None;
        }
        let len = core::mem::take(&mut self.len);
        if core::mem::take(&mut self.overflowed) {
            return Some(Err(FrameError::TooLarge));
        }
        if len == 0 {
            return None;
        }
        Some(unstuff(&mut self.buf[..len]).and_then(decode))
    }

    /// Feeds a buffer, calling `on_frame` for every frame it completes. Equivalent to
    /// [`push`](Self::push) for every byte, but copies runs of frame bytes at once.
    pub fn feed<T: DeserializeOwned>(
        &mut self,
        bytes: &[u8],
        mut on_frame: impl FnMut(Result<T, FrameError>),
    ) {
        self.feed_with(bytes, |decoder, byte| {
            if let Some(result) = decoder.push(byte) {
                on_frame(result);
            }
        });
    }

    /// [`feed`](Self::feed) with every frame checked against `inbound`, as
    /// [`push_checked`](Self::push_checked) does.
    pub fn feed_checked<T: DeserializeOwned>(
        &mut self,
        bytes: &[u8],
        inbound: &mut Inbound,
        mut on_frame: impl FnMut(Result<T, FrameError>),
    ) {
        self.feed_with(bytes, |decoder, byte| {
            if let Some(result) = decoder.push_checked(byte, inbound) {
                on_frame(result);
            }
        });
    }

    /// Copies runs of frame bytes at once and hands each delimiter to `delimit`.
    fn feed_with(&mut self, mut bytes: &[u8], mut delimit: impl FnMut(&mut Self, u8)) {
        while !bytes.is_empty() {
            let run = bytes.iter().position(|&b| b == 0).unwrap_or(bytes.len());
            let (body, rest) = bytes.split_at(run);
            let room = self.buf.len() - self.len;
            if body.len() > room {
                self.overflowed = true;
                self.len = self.buf.len();
            } else {
                self.buf[self.len..self.len + body.len()].copy_from_slice(body);
                self.len += body.len();
            }
            match rest.split_first() {
                Some((&delimiter, tail)) => {
                    delimit(self, delimiter);
                    bytes = tail;
                }
                None => bytes = rest,
            }
        }
    }
}

/// Undoes the stuffing and checks the CRC; returns the payload.
fn unstuff(stuffed: &mut [u8]) -> Result<&[u8], FrameError> {
    let len = cobs::decode_in_place(stuffed).map_err(|_| FrameError::BadStuffing)?;
    if len < CRC_LEN {
        return Err(FrameError::BadStuffing);
    }
    let (payload, trailer) = stuffed[..len].split_at(len - CRC_LEN);
    let mut crc = [0u8; CRC_LEN];
    crc.copy_from_slice(trailer);
    if frame_crc(payload) != u32::from_le_bytes(crc) {
        return Err(FrameError::BadCrc);
    }
    Ok(payload)
}

/// A payload that is exactly one message.
fn decode_plain<T: DeserializeOwned>(payload: &[u8]) -> Result<T, FrameError> {
    match postcard::take_from_bytes::<T>(payload) {
        Ok((message, [])) => Ok(message),
        _ => Err(FrameError::Malformed),
    }
}

/// A payload that is one message, followed by a seal or not, as `inbound` requires; the
/// seal is checked before anything is decoded.
fn decode_checked<T: DeserializeOwned>(
    payload: &[u8],
    inbound: &mut Inbound,
) -> Result<T, FrameError> {
    match inbound.accept(payload)? {
        Accepted::Sealed(message) => decode_plain(message),
        Accepted::Plain(message) => match postcard::take_from_bytes::<T>(message) {
            Ok((message, [])) => Ok(message),
            // A seal that did not verify, on a receiver that still takes plain frames.
            _ if inbound.has_key() && message.len() > SEAL_LEN => Err(FrameError::BadSeal),
            // What a sealed frame looks like to a receiver with no session key.
            Ok((_, rest)) if rest.len() == SEAL_LEN && !inbound.has_key() => {
                Err(FrameError::UnexpectedSeal)
            }
            _ => Err(FrameError::Malformed),
        },
    }
}
