//! The single-controller rule: one network client at a time may control the motors.
//!
//! A network session claims control when it first runs a control command (after passing
//! authentication); while it holds the claim, every other network session's control
//! commands get `busy`. Open commands (`Status`, `GetConfig`, `EmergencyStop`, the
//! handshake and authentication) stay open to everyone, and serial sessions are trusted
//! and never blocked (physical access). The claim is released when the embedder ends the
//! holding session ([`Controller::end_session`]) or when a new key revokes the holder's
//! authentication.

use optalign_protocol::{Access, Command, ErrorCode, ErrorReply, error_reply};

use crate::controller::Controller;
use crate::session::{LinkKind, Session};
use crate::storage::Storage;

/// Who holds control: the claim given to one session, under the key it authenticated with.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Holder {
    claim: u32,
    key_epoch: u32,
}

/// The control claim of a controller.
#[derive(Debug, Default)]
pub(crate) struct ControlClaim {
    holder: Option<Holder>,
    /// The claim number the next claiming session gets.
    next: u32,
}

impl ControlClaim {
    /// Lets `session` run `command`, claiming control for it if nobody holds it.
    fn admit(
        &mut self,
        session: &mut Session,
        command: &Command,
        key_epoch: u32,
    ) -> Result<(), ErrorReply> {
        if command.access() != Access::Control || session.link() == LinkKind::Serial {
            return Ok(());
        }
        match self.holder {
            Some(holder) if holder.key_epoch == key_epoch => {
                if session.claim == Some(holder.claim) {
                    Ok(())
                } else {
                    Err(error_reply!(
                        ErrorCode::BUSY,
                        "another client controls this controller until it disconnects; \
                         Status, GetConfig and EmergencyStop stay open"
                    ))
                }
            }
            // Free, or held under a key that has since been replaced.
            _ => {
                let claim = self.next;
                self.next = self.next.wrapping_add(1);
                self.holder = Some(Holder { claim, key_epoch });
                session.claim = Some(claim);
                Ok(())
            }
        }
    }

    fn release(&mut self, session: &Session) {
        if session
            .claim
            .is_some_and(|claim| self.holder.is_some_and(|h| h.claim == claim))
        {
            self.holder = None;
        }
    }
}

impl<S: Storage> Controller<S> {
    /// Ends `session` (its connection closed): releases control if it held it and resets
    /// it to a fresh, unauthenticated session. Embedders call this on every disconnect.
    pub fn end_session(&mut self, session: &mut Session) {
        self.control.release(session);
        *session = Session::new(session.link());
    }

    /// Applies the single-controller rule to `command` from `session`.
    pub(crate) fn admit(
        &mut self,
        session: &mut Session,
        command: &Command,
    ) -> Result<(), ErrorReply> {
        let key_epoch = self.key_epoch;
        self.control.admit(session, command, key_epoch)
    }
}
