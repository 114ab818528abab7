//! The request-id memory that makes retries safe.
//!
//! The replies to the last [`CAPACITY`] requests with an effect (stops excepted) are kept, keyed by request
//! id and a fingerprint (CRC-32C) of the command, in one memory for all sessions: a client
//! that reconnects and retransmits gets the cached reply and nothing runs twice. A known id
//! carrying a different command is a new request (two clients may pick the same id).

use crc::{CRC_32_ISCSI, Crc};
use optalign_protocol::{Command, ErrorReply, MAX_PAYLOAD, Reply, RequestId};

/// Requests remembered.
pub const CAPACITY: usize = 16;

const CRC32C: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// The replies a command with an effect can get.
#[derive(Clone, Debug, PartialEq)]
enum Cached {
    MoveStarted(u32),
    Ok,
    Error(ErrorReply),
}

impl Cached {
    fn from_reply(reply: &Reply) -> Option<Self> {
        match reply {
            Reply::MoveStarted { duration_ms } => Some(Self::MoveStarted(*duration_ms)),
            Reply::Ok => Some(Self::Ok),
            Reply::Error(error) => Some(Self::Error(error.clone())),
            Reply::Hello(_)
            | Reply::Status(_)
            | Reply::Config(_)
            | Reply::Challenge { .. }
            | Reply::MoveResult(_)
            | Reply::Refused { .. } => None,
        }
    }

    fn to_reply(&self) -> Reply {
        match self {
            Self::MoveStarted(duration_ms) => Reply::MoveStarted {
                duration_ms: *duration_ms,
            },
            Self::Ok => Reply::Ok,
            Self::Error(error) => Reply::Error(error.clone()),
        }
    }
}

struct Entry {
    id: RequestId,
    fingerprint: u32,
    reply: Cached,
}

/// A ring of the most recent replies.
pub struct ReplyCache {
    entries: [Option<Entry>; CAPACITY],
    next: usize,
}

impl ReplyCache {
    pub fn new() -> Self {
        Self {
            entries: [const { None }; CAPACITY],
            next: 0,
        }
    }

    /// Whether a command's reply belongs here: it has an effect beyond its session.
    /// Authentication only concerns the session that asks, so it is never replayed; stops
    /// always run (running one twice is the same as once) and never take a place here, so
    /// that anyone's stops cannot push the controlling client's replies out.
    pub fn applies_to(command: &Command) -> bool {
        command.has_effect()
            && !matches!(
                command,
                Command::AuthChallenge
                    | Command::AuthResponse { .. }
                    | Command::Stop
                    | Command::EmergencyStop
            )
    }

    /// Identifies a command's content.
    pub fn fingerprint(command: &Command) -> u32 {
        let mut buf = [0u8; MAX_PAYLOAD];
        postcard::to_slice(command, &mut buf).map_or(0, |bytes| CRC32C.checksum(bytes))
    }

    pub fn lookup(&self, id: RequestId, fingerprint: u32) -> Option<Reply> {
        self.entries
            .iter()
            .flatten()
            .find(|e| e.id == id && e.fingerprint == fingerprint)
            .map(|e| e.reply.to_reply())
    }

    pub fn remember(&mut self, id: RequestId, fingerprint: u32, reply: &Reply) {
        let Some(reply) = Cached::from_reply(reply) else {
            return;
        };
        let entry = Entry {
            id,
            fingerprint,
            reply,
        };
        // A reused id replaces its old entry.
        if let Some(slot) = self
            .entries
            .iter_mut()
            .find(|e| e.as_ref().is_some_and(|e| e.id == id))
        {
            *slot = Some(entry);
            return;
        }
        if let Some(slot) = self.entries.get_mut(self.next) {
            *slot = Some(entry);
        }
        self.next = (self.next + 1) % CAPACITY;
    }
}

#[cfg(test)]
mod tests {
    use optalign_protocol::error_reply;
    use optalign_protocol::{AxisValue, ErrorCode};

    use super::*;

    fn move_to(steps: i32) -> Command {
        Command::MoveTo {
            targets: [AxisValue { axis: 0, steps }].into_iter().collect(),
        }
    }

    #[test]
    fn remembers_the_last_sixteen() {
        let mut cache = ReplyCache::new();
        let fp = ReplyCache::fingerprint(&move_to(1));
        for id in 0..20 {
            cache.remember(RequestId(id), fp, &Reply::MoveStarted { duration_ms: id });
        }
        assert_eq!(cache.lookup(RequestId(3), fp), None);
        assert_eq!(
            cache.lookup(RequestId(4), fp),
            Some(Reply::MoveStarted { duration_ms: 4 })
        );
        assert_eq!(
            cache.lookup(RequestId(19), fp),
            Some(Reply::MoveStarted { duration_ms: 19 })
        );
    }

    #[test]
    fn same_id_other_command_is_new() {
        let mut cache = ReplyCache::new();
        let (a, b) = (
            ReplyCache::fingerprint(&move_to(1)),
            ReplyCache::fingerprint(&move_to(2)),
        );
        assert_ne!(a, b);
        let error = Reply::Error(error_reply!(ErrorCode::OUT_OF_LIMITS, "x"));
        cache.remember(RequestId(1), a, &error);
        assert_eq!(cache.lookup(RequestId(1), a), Some(error));
        assert_eq!(cache.lookup(RequestId(1), b), None);
        cache.remember(RequestId(1), b, &Reply::Ok);
        assert_eq!(cache.lookup(RequestId(1), a), None);
        assert_eq!(cache.lookup(RequestId(1), b), Some(Reply::Ok));
    }

    #[test]
    fn what_is_replayed() {
        assert!(ReplyCache::applies_to(&move_to(0)));
        assert!(ReplyCache::applies_to(&Command::ClearEmergency));
        assert!(!ReplyCache::applies_to(&Command::EmergencyStop));
        assert!(!ReplyCache::applies_to(&Command::Stop));
        assert!(!ReplyCache::applies_to(&Command::Status));
        assert!(!ReplyCache::applies_to(&Command::AuthChallenge));
        assert!(!ReplyCache::applies_to(&Command::AuthResponse {
            tag: [0; 32],
            client_nonce: [0; 16],
        }));
    }
}
