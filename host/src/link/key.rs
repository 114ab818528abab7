//! Access keys on the host: a passphrase stretched with Argon2id, salted with the board id,
//! or the 32 derived bytes themselves, given in hex.
//!
//! The controller stores only the derived 32 bytes (`SetKey` over serial). Stretching makes
//! every guess of an offline dictionary attack on a captured handshake cost
//! [`MEMORY_KIB`] KiB of memory and [`ITERATIONS`] passes over it, and the salt (the board
//! id, which `Identity` carries) means one table of guesses serves one board only. The
//! parameters take a few tens of milliseconds on a lab PC; a [`crate::link::Client`]
//! derives once per board and keeps the result.

use std::fmt;
use std::str::FromStr;

use argon2::{Algorithm, Argon2, Params, Version};
use optalign_protocol::auth::Key;
use optalign_protocol::limits::KEY_LEN;

/// Argon2id memory cost, KiB (19 MiB: OWASP's minimum for Argon2id with two passes).
pub const MEMORY_KIB: u32 = 19 * 1024;
/// Argon2id passes over the memory.
pub const ITERATIONS: u32 = 2;
/// Argon2id lanes.
pub const LANES: u32 = 1;

/// Domain separation in the salt, ahead of the board id.
const SALT_CONTEXT: &[u8] = b"optalign-key-v2";

/// What introduces a key given as hex instead of a passphrase.
pub const HEX_PREFIX: &str = "hex:";

/// An access key as the user gives it.
#[derive(Clone, PartialEq, Eq)]
pub enum AccessKey {
    /// A passphrase, stretched for each board it is used with.
    Passphrase(String),
    /// The derived key itself (`hex:` and 64 hex digits), used as is on any board.
    Derived(Key),
}

impl AccessKey {
    /// A passphrase key.
    pub fn passphrase(passphrase: &str) -> Self {
        Self::Passphrase(passphrase.to_owned())
    }

    /// The 32 bytes this key means on the board with `board_id` (tens of ms for a
    /// passphrase: run it off the async executor).
    pub fn for_board(&self, board_id: u64) -> Key {
        match self {
            Self::Passphrase(passphrase) => stretch(passphrase, board_id),
            Self::Derived(key) => *key,
        }
    }
}

impl fmt::Debug for AccessKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::Passphrase(_) => "AccessKey::Passphrase(..)",
            Self::Derived(_) => "AccessKey::Derived(..)",
        })
    }
}

/// Why a key was not understood.
#[derive(Debug, PartialEq, Eq, thiserror::Error)]
pub enum KeyError {
    #[error("the access key is empty")]
    Empty,
    #[error(
        "a hex access key needs exactly {digits} hex digits after `{HEX_PREFIX}`, got {0} characters",
        digits = KEY_LEN * 2
    )]
    HexLength(usize),
    #[error("a hex access key has a character that is not a hex digit: {0:?}")]
    NotHex(char),
}

impl FromStr for AccessKey {
    type Err = KeyError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let Some(hex) = text.strip_prefix(HEX_PREFIX) else {
            if text.is_empty() {
                return Err(KeyError::Empty);
            }
            return Ok(Self::passphrase(text));
        };
        if let Some(bad) = hex.chars().find(|c| !c.is_ascii_hexdigit()) {
            return Err(KeyError::NotHex(bad));
        }
        if hex.len() != KEY_LEN * 2 {
            return Err(KeyError::HexLength(hex.len()));
        }
        let mut key = [0u8; KEY_LEN];
        for (byte, pair) in key.iter_mut().zip(hex.as_bytes().chunks_exact(2)) {
            let digits = std::str::from_utf8(pair).map_err(|_| KeyError::NotHex('?'))?;
            *byte = u8::from_str_radix(digits, 16).map_err(|_| KeyError::NotHex('?'))?;
        }
        Ok(Self::Derived(key))
    }
}

/// The key `passphrase` stretches to for the board with `board_id`.
pub fn stretch(passphrase: &str, board_id: u64) -> Key {
    let params = Params::new(MEMORY_KIB, ITERATIONS, LANES, Some(KEY_LEN))
        .expect("the Argon2id parameters are valid constants");
    let mut salt = [0u8; SALT_CONTEXT.len() + 8];
    salt[..SALT_CONTEXT.len()].copy_from_slice(SALT_CONTEXT);
    salt[SALT_CONTEXT.len()..].copy_from_slice(&board_id.to_le_bytes());
    let mut key = [0u8; KEY_LEN];
    Argon2::new(Algorithm::Argon2id, Version::V0x13, params)
        .hash_password_into(passphrase.as_bytes(), &salt, &mut key)
        .expect("any passphrase and this salt are within Argon2's limits");
    key
}

/// `key` as `hex:` and 64 hex digits, as [`AccessKey`] reads it.
pub fn to_hex(key: &Key) -> String {
    let digits: String = key.iter().map(|b| format!("{b:02x}")).collect();
    format!("{HEX_PREFIX}{digits}")
}

#[cfg(test)]
mod tests {
    use std::time::Instant;

    use super::*;

    #[test]
    fn a_passphrase_stretches_differently_per_board_and_per_passphrase() {
        let started = Instant::now();
        let key = stretch("correct horse", 1);
        let once = started.elapsed();
        assert_eq!(key, stretch("correct horse", 1));
        assert_ne!(key, stretch("correct horse", 2), "the board id salts it");
        assert_ne!(key, stretch("correct horse ", 1));
        assert!(once.as_millis() < 2_000, "{once:?} for one derivation");
    }

    #[test]
    fn a_hex_key_is_used_as_is_and_round_trips() {
        let derived = stretch("lab key", 9);
        let text = to_hex(&derived);
        let parsed: AccessKey = text.parse().unwrap();
        assert_eq!(parsed, AccessKey::Derived(derived));
        assert_eq!(parsed.for_board(9), derived);
        assert_eq!(
            parsed.for_board(10),
            derived,
            "hex keys are not salted again"
        );
        assert_eq!(
            "lab key".parse::<AccessKey>().unwrap().for_board(9),
            derived
        );
    }

    #[test]
    fn malformed_keys_are_refused_with_the_reason() {
        assert_eq!("".parse::<AccessKey>(), Err(KeyError::Empty));
        assert_eq!("hex:abc".parse::<AccessKey>(), Err(KeyError::HexLength(3)));
        let bad = format!("hex:{}", "g".repeat(64));
        assert_eq!(bad.parse::<AccessKey>(), Err(KeyError::NotHex('g')));
        assert_eq!(
            KeyError::HexLength(3).to_string(),
            "a hex access key needs exactly 64 hex digits after `hex:`, got 3 characters"
        );
        assert!(
            format!("{:?}", AccessKey::passphrase("secret"))
                .find("secret")
                .is_none()
        );
    }
}
