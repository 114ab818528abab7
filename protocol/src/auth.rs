//! Access control for network links: a pre-shared key and an HMAC-SHA256 challenge.
//!
//! The peer issues a random nonce; the client proves it holds the key by returning
//! `HMAC-SHA256(key, CONTEXT || nonce)`. The key itself never crosses the network: it is
//! set over the serial link, which is trusted because it needs physical access.

use hmac::{Hmac, KeyInit, Mac};
use sha2::{Digest, Sha256};

use crate::limits::{KEY_LEN, NONCE_LEN};

/// A pre-shared access key.
pub type Key = [u8; KEY_LEN];

/// Domain separation for challenge tags, so a tag can never be replayed elsewhere.
const CONTEXT: &[u8] = b"optalign-auth-v1";

/// Domain separation for turning a passphrase into a key.
const KEY_CONTEXT: &[u8] = b"optalign-key-v1";

/// Derives the 32-byte key from a passphrase, the same way on the host and the peer.
pub fn derive_key(passphrase: &str) -> Key {
    let mut hasher = Sha256::new();
    hasher.update(KEY_CONTEXT);
    hasher.update(passphrase.as_bytes());
    hasher.finalize().into()
}

/// The tag that answers `nonce` under `key`.
pub fn challenge_tag(key: &Key, nonce: &[u8; NONCE_LEN]) -> [u8; KEY_LEN] {
    mac(key, nonce).finalize().into_bytes().into()
}

/// Checks a tag in constant time.
pub fn verify_tag(key: &Key, nonce: &[u8; NONCE_LEN], tag: &[u8; KEY_LEN]) -> bool {
    mac(key, nonce).verify_slice(tag).is_ok()
}

fn mac(key: &Key, nonce: &[u8; NONCE_LEN]) -> Hmac<Sha256> {
    let mut mac =
        <Hmac<Sha256> as KeyInit>::new_from_slice(key).expect("HMAC accepts keys of any length");
    mac.update(CONTEXT);
    mac.update(nonce);
    mac
}
