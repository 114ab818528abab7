//! The cryptography of authentication, split from the handling of its requests so that an
//! embedder can run it outside its lock on the controller.
//!
//! `AuthChallenge` costs a SHA-256 (the nonce's mix, [`crate::nonce`]) and `AuthResponse`
//! two HMAC-SHA256 (the tag, then the session key): about 0.6 ms on a Cortex-M0+. A board
//! whose motion task shares the controller with its links would hold that task off that
//! long, so [`Controller::begin`](crate::Controller::begin) does everything else and hands
//! back the [`Work`], the embedder runs it with the lock released ([`Work::run`]), and
//! [`Controller::finish`](crate::Controller::finish) applies what it found.
//! [`Controller::handle`](crate::Controller::handle) does the three in a row.

use optalign_protocol::RequestId;
use optalign_protocol::auth::{Key, Nonce, SessionKey, session_key, verify_tag};
use optalign_protocol::limits::KEY_LEN;

use crate::nonce::Draw;
use crate::session::RngSource;

/// Cryptography a request needs before it is answered.
#[derive(Debug)]
pub struct Work(Task);

#[derive(Debug)]
enum Task {
    /// A fresh challenge nonce for the request `id`.
    Challenge { id: RequestId, draw: Draw },
    /// Whether a response's tag verifies, and the session key when it does.
    Response {
        key: Key,
        epoch: u32,
        nonce: Nonce,
        client_nonce: Nonce,
        tag: [u8; KEY_LEN],
    },
}

/// What the cryptography found, for [`Controller::finish`](crate::Controller::finish).
#[derive(Debug)]
pub struct Done(pub(crate) Outcome);

#[derive(Debug)]
pub(crate) enum Outcome {
    Challenge {
        id: RequestId,
        nonce: Nonce,
    },
    Response {
        /// The key generation the response was checked against.
        epoch: u32,
        /// The session key, when the tag verified.
        channel: Option<SessionKey>,
    },
}

impl Work {
    pub(crate) fn challenge(id: RequestId, draw: Draw) -> Self {
        Self(Task::Challenge { id, draw })
    }

    pub(crate) fn response(
        key: Key,
        epoch: u32,
        nonce: Nonce,
        client_nonce: Nonce,
        tag: [u8; KEY_LEN],
    ) -> Self {
        Self(Task::Response {
            key,
            epoch,
            nonce,
            client_nonce,
            tag,
        })
    }

    /// Does the cryptography; `rng` gives the nonce's fresh entropy.
    pub fn run(self, rng: &mut dyn RngSource) -> Done {
        Done(match self.0 {
            Task::Challenge { id, draw } => Outcome::Challenge {
                id,
                nonce: draw.nonce(rng),
            },
            Task::Response {
                key,
                epoch,
                nonce,
                client_nonce,
                tag,
            } => Outcome::Response {
                epoch,
                channel: verify_tag(&key, &nonce, &client_nonce, &tag)
                    .then(|| session_key(&key, &nonce, &client_nonce)),
            },
        })
    }
}
