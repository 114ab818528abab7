//! Access control for network links: a pre-shared key, an HMAC-SHA256 challenge that both
//! sides' nonces enter, and the session key both sides derive from it.
//!
//! The peer issues a random nonce; the client draws its own and proves it holds the key by
//! returning `HMAC-SHA256(key, AUTH_CONTEXT || peer nonce || client nonce)` with its nonce.
//! Both sides then derive `HMAC-SHA256(key, SESSION_CONTEXT || peer nonce || client nonce)`
//! as the session key that authenticates every later frame ([`crate::seal`]). The key itself
//! never crosses the network: it is set over the serial link, which is trusted because it
//! needs physical access. How a passphrase becomes the key is the host's business (it
//! stretches it with Argon2id, salted with the board id); the controller stores the 32 bytes.

use hmac::{Hmac, KeyInit, Mac};
use sha2::Sha256;

use crate::limits::{KEY_LEN, NONCE_LEN};

/// A pre-shared access key.
pub type Key = [u8; KEY_LEN];

/// A key that authenticates the frames of one session.
pub type SessionKey = [u8; KEY_LEN];

/// A challenge nonce (drawn by the peer, or by the client).
pub type Nonce = [u8; NONCE_LEN];

/// Domain separation for challenge tags, so a tag can never be replayed elsewhere.
const AUTH_CONTEXT: &[u8] = b"optalign-auth-v2";

/// Domain separation for session keys, so a session key is never a valid tag.
const SESSION_CONTEXT: &[u8] = b"optalign-session-v1";

/// The tag that answers the peer's `nonce` under `key`, for a client that drew `client_nonce`.
pub fn challenge_tag(key: &Key, nonce: &Nonce, client_nonce: &Nonce) -> [u8; KEY_LEN] {
    keyed(key, AUTH_CONTEXT, nonce, client_nonce)
        .finalize()
        .into_bytes()
        .into()
}

/// Checks a tag in constant time.
pub fn verify_tag(key: &Key, nonce: &Nonce, client_nonce: &Nonce, tag: &[u8; KEY_LEN]) -> bool {
    keyed(key, AUTH_CONTEXT, nonce, client_nonce)
        .verify_slice(tag)
        .is_ok()
}

/// The session key both sides derive once the tag for `nonce` and `client_nonce` verified.
pub fn session_key(key: &Key, nonce: &Nonce, client_nonce: &Nonce) -> SessionKey {
    keyed(key, SESSION_CONTEXT, nonce, client_nonce)
        .finalize()
        .into_bytes()
        .into()
}

fn keyed(key: &Key, context: &[u8], nonce: &Nonce, client_nonce: &Nonce) -> Hmac<Sha256> {
    let mut mac =
        <Hmac<Sha256> as KeyInit>::new_from_slice(key).expect("HMAC accepts keys of any length");
    mac.update(context);
    mac.update(nonce);
    mac.update(client_nonce);
    mac
}
