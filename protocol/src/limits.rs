//! Protocol-wide constants: the version number and the sizes every buffer is built from.

/// The protocol version spoken by this build. Peers refuse a handshake with any other.
///
/// Bump it whenever the encoding of any message changes. `Command::Hello` and the error
/// replies are frozen, and a peer answers a `Hello` of another version with one of them
/// (never with an `Identity`), so a mismatch can always be reported: `Reply::Refused`
/// naming its own version to a client of version [`REFUSED_SINCE`] or later, the plain
/// `Reply::Error` to an older one, which does not know `Refused`.
pub const PROTOCOL_VERSION: u16 = 5;

/// The first version that knows `Reply::Refused`.
pub const REFUSED_SINCE: u16 = 5;

/// Most axes one controller exposes (a Pico W drives four; the simulated peer up to eight).
pub const MAX_AXES: usize = 8;

/// Largest serialized message, before the CRC and COBS stuffing are added.
pub const MAX_PAYLOAD: usize = 480;

/// Largest frame on the wire: payload, seal, 4-byte CRC, COBS overhead and the 0x00
/// delimiter.
pub const MAX_FRAME: usize = 512;

/// Bytes of the CRC-32C trailer inside each frame.
pub const CRC_LEN: usize = 4;

/// Longest human-readable reason carried by an error reply.
pub const REASON_LEN: usize = 96;

/// Longest Wi-Fi SSID (802.11 limit).
pub const SSID_LEN: usize = 32;

/// Longest WPA2 passphrase.
pub const PASSPHRASE_LEN: usize = 64;

/// Size of the challenge nonce a peer issues for authentication.
pub const NONCE_LEN: usize = 16;

/// Size of the pre-shared key, of session keys and of the HMAC-SHA256 challenge tag.
pub const KEY_LEN: usize = 32;

const SEALED: usize = MAX_PAYLOAD + crate::seal::SEAL_LEN + CRC_LEN;
const _: () = assert!(SEALED + SEALED / 254 + 2 <= MAX_FRAME);
