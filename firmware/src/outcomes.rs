//! The outcomes of the latest moves by request id, for a host that missed a
//! `MoveFinished` (its link dropped): it asks `MoveResult` instead of guessing from
//! positions.
//!
//! The last [`CAPACITY`] accepted moves are kept, in RAM: a restart forgets them, which a
//! host notices by the boot nonce.

use heapless::Vec;
use optalign_protocol::{MAX_AXES, MoveOutcome, MoveResult, RequestId};

/// Moves remembered.
pub const CAPACITY: usize = 16;

struct Entry {
    request: RequestId,
    result: MoveResult,
}

/// A ring of the most recent moves.
pub struct MoveLog {
    entries: [Option<Entry>; CAPACITY],
    next: usize,
}

impl MoveLog {
    pub fn new() -> Self {
        Self {
            entries: [const { None }; CAPACITY],
            next: 0,
        }
    }

    /// Records that the move started by `request` was accepted.
    pub fn started(&mut self, request: RequestId) {
        self.put(request, MoveResult::InProgress);
    }

    /// Records how the move started by `request` ended.
    pub fn finished(
        &mut self,
        request: RequestId,
        outcome: MoveOutcome,
        positions: Vec<i32, MAX_AXES>,
    ) {
        self.put(request, MoveResult::Finished { outcome, positions });
    }

    /// What became of the move started by `request`.
    pub fn lookup(&self, request: RequestId) -> MoveResult {
        self.entries
            .iter()
            .flatten()
            .find(|e| e.request == request)
            .map_or(MoveResult::Unknown, |e| e.result.clone())
    }

    /// Updates `request`'s entry, or takes the oldest slot for it.
    fn put(&mut self, request: RequestId, result: MoveResult) {
        if let Some(entry) = self
            .entries
            .iter_mut()
            .flatten()
            .find(|e| e.request == request)
        {
            entry.result = result;
            return;
        }
        if let Some(slot) = self.entries.get_mut(self.next) {
            *slot = Some(Entry { request, result });
        }
        self.next = (self.next + 1) % CAPACITY;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn remembers_the_last_moves_and_their_ends() {
        let mut log = MoveLog::new();
        assert_eq!(log.lookup(RequestId(1)), MoveResult::Unknown);
        log.started(RequestId(1));
        assert_eq!(log.lookup(RequestId(1)), MoveResult::InProgress);
        let positions: Vec<i32, MAX_AXES> = [5, -3].into_iter().collect();
        log.finished(RequestId(1), MoveOutcome::Stopped, positions.clone());
        let stopped = MoveResult::Finished {
            outcome: MoveOutcome::Stopped,
            positions,
        };
        assert_eq!(log.lookup(RequestId(1)), stopped);
        // Finishing updates the entry in place: fifteen more moves keep it.
        for id in 2..=CAPACITY as u32 {
            log.started(RequestId(id));
        }
        assert_eq!(log.lookup(RequestId(1)), stopped);
        log.started(RequestId(100));
        assert_eq!(log.lookup(RequestId(1)), MoveResult::Unknown);
        assert_eq!(log.lookup(RequestId(2)), MoveResult::InProgress);
    }
}
