//! The requests waiting for their replies on one connection.
//!
//! The connection's reader hands each reply to its waiter and, when the link ends, closes
//! the table: every waiter learns at once, and a request sent after that cannot wait on a
//! link that will never answer (a controller that closed a connection right after taking
//! it would otherwise hold the request for its whole timeout).

use std::collections::HashMap;
use std::sync::Mutex;

use optalign_protocol::Reply;
use tokio::sync::oneshot;

/// Waiters by request id; `None` once the connection's reader has ended.
pub struct Waiters(Mutex<Option<HashMap<u32, oneshot::Sender<Reply>>>>);

impl Waiters {
    /// An open table with nobody waiting.
    pub fn new() -> Self {
        Self(Mutex::new(Some(HashMap::new())))
    }

    /// Waits for the reply to request `id`; `None` when the link has already ended.
    pub fn wait_for(&self, id: u32) -> Option<oneshot::Receiver<Reply>> {
        let (sender, receiver) = oneshot::channel();
        self.table().as_mut()?.insert(id, sender);
        Some(receiver)
    }

    /// Gives `reply` to whoever waits for request `id`; false when nobody does.
    pub fn answer(&self, id: u32, reply: Reply) -> bool {
        let waiter = self.table().as_mut().and_then(|table| table.remove(&id));
        waiter.is_some_and(|waiter| waiter.send(reply).is_ok())
    }

    /// Stops waiting for request `id` (it timed out).
    pub fn forget(&self, id: u32) {
        if let Some(table) = self.table().as_mut() {
            table.remove(&id);
        }
    }

    /// The link ended: every waiter is told, and nobody may wait any more.
    pub fn close(&self) {
        self.table().take();
    }

    fn table(&self) -> std::sync::MutexGuard<'_, Option<HashMap<u32, oneshot::Sender<Reply>>>> {
        self.0.lock().unwrap_or_else(|e| e.into_inner())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use optalign_protocol::{ErrorCode, ErrorReply};

    fn reply() -> Reply {
        Reply::Error(ErrorReply::new(ErrorCode::BUSY, format_args!("busy")))
    }

    #[test]
    fn a_reply_reaches_its_waiter_and_only_once() {
        let waiters = Waiters::new();
        let mut receiver = waiters.wait_for(7).unwrap();
        assert!(!waiters.answer(8, reply()), "nobody waits for 8");
        assert!(waiters.answer(7, reply()));
        assert!(receiver.try_recv().is_ok());
        assert!(!waiters.answer(7, reply()), "7 was answered already");
    }

    #[test]
    fn closing_tells_every_waiter_and_refuses_later_ones() {
        let waiters = Waiters::new();
        let mut first = waiters.wait_for(1).unwrap();
        let mut forgotten = waiters.wait_for(2).unwrap();
        waiters.forget(2);
        assert!(forgotten.try_recv().is_err());
        waiters.close();
        assert!(matches!(
            first.try_recv(),
            Err(oneshot::error::TryRecvError::Closed)
        ));
        assert!(
            waiters.wait_for(3).is_none(),
            "a request sent after the link ended cannot wait on it"
        );
    }
}
