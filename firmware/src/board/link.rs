//! Serving the protocol on one byte stream (a TCP connection, USB serial, UART0) with the
//! core's [`Connection`], which holds every rule of a connection: this module only moves
//! bytes and time.
//!
//! Bytes read go to the connection, each answer is written back at once, and the
//! notifications the motion task publishes are written in between. The stream is closed
//! when the connection says so ([`Connection::close_at_us`]), when a write is not taken
//! within its deadline ([`Connection::send_deadline_us`]), when the network admission
//! table evicts it ([`NETWORK`], through its [`Evictions`] signal), or when it ends; then
//! the connection ends, which releases control of the motors if it held it and frees its
//! network slot.

use core::cell::RefCell;

use embassy_futures::select::{Either4, select4};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pubsub::WaitResult;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer, with_deadline};
use embedded_io_async::{Read, Write};
use optalign_protocol::{FrameError, MAX_FRAME, PeerMessage, Request};

use super::log::{info, warn};
use super::motion::{LOOKAHEAD_US, NOTES, WAKE};
use super::rng::Nonces;
use super::{SharedCore, now_us};
use crate::admission::{Admissions, LOBBY, Standing, Ticket};
use crate::connection::{Connection, Port, Received};
use crate::session::Session;

/// Network slots: TCP connections served with full rights.
pub const SLOTS: usize = 3;

/// Sessions open at once: USB (or UART) plus the TCP connections, in slots and the lobby.
pub const MAX_SESSIONS: usize = 1 + SLOTS + LOBBY;

/// The signal that closes a network connection the admission table evicted.
pub type Evictions = Signal<CriticalSectionRawMutex, ()>;

/// One eviction signal per TCP task, indexed by the task's token in [`NETWORK`].
pub static EVICTED: [Evictions; SLOTS + LOBBY] = [const { Evictions::new() }; SLOTS + LOBBY];

/// The network admission table; a token is the serving TCP task's index.
pub static NETWORK: Mutex<CriticalSectionRawMutex, RefCell<Admissions<usize>>> =
    Mutex::new(RefCell::new(Admissions::new(SLOTS, LOBBY)));

/// Closes the connection of the TCP task `evicted`, if any.
pub fn evict(evicted: Option<usize>) {
    if let Some(signal) = evicted.and_then(|task| EVICTED.get(task)) {
        signal.signal(());
    }
}

/// The core and the admission table, as a connection reaches them.
struct BoardPort(&'static SharedCore);

impl Port for BoardPort {
    fn request(
        &mut self,
        session: &mut Session,
        request: &Request,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        // At the lookahead horizon, where the motion task keeps the core's clock: a move
        // planned now starts after everything already queued, and its first pin change is
        // queued ahead of its time like every later one.
        let horizon = || now_us() + LOOKAHEAD_US;
        let work = self
            .0
            .lock(|cell| cell.borrow_mut().begin(session, request, horizon(), out));
        // Authentication's hashing, with the core free for the motion task meanwhile.
        if let Some(work) = work {
            let done = work.run(&mut Nonces);
            self.0.lock(|cell| {
                cell.borrow_mut()
                    .finish(session, request, done, horizon(), out)
            });
        }
        WAKE.signal(());
    }

    fn link_error(&mut self, error: FrameError, out: &mut dyn FnMut(PeerMessage)) {
        self.0.lock(|cell| cell.borrow_mut().link_error(error, out));
    }

    fn standing(&mut self, ticket: Ticket, standing: Standing) {
        NETWORK.lock(|table| table.borrow_mut().standing(ticket, standing));
    }

    fn promote(&mut self, ticket: Ticket) -> Option<Ticket> {
        let now = now_us();
        let promotion = NETWORK.lock(|table| table.borrow_mut().promote(ticket, now))?;
        evict(promotion.evicted);
        Some(promotion.ticket)
    }

    fn end(&mut self, session: &mut Session, ticket: Ticket) {
        self.0.lock(|cell| cell.borrow_mut().end_session(session));
        NETWORK.lock(|table| table.borrow_mut().release(ticket));
        WAKE.signal(());
    }
}

/// Serves `connection` on `rx`/`tx` until it is closed (by the stream, its deadlines or
/// `evicted`), then ends it.
pub async fn serve<R: Read, W: Write>(
    core: &'static SharedCore,
    mut connection: Connection,
    rx: &mut R,
    tx: &mut W,
    evicted: Option<&Evictions>,
) {
    let mut port = BoardPort(core);
    let Ok(mut notes) = NOTES.subscriber() else {
        warn!("link: no room for another session");
        connection.end(&mut port);
        return;
    };
    let mut bytes = [0u8; 64];
    'stream: loop {
        let close = connection
            .close_at_us()
            .map_or(Instant::MAX, Instant::from_micros);
        let eviction = async {
            match evicted {
                Some(signal) => signal.wait().await,
                None => core::future::pending().await,
            }
        };
        let event = select4(
            rx.read(&mut bytes),
            notes.next_message(),
            Timer::at(close),
            eviction,
        )
        .await;
        match event {
            Either4::First(Ok(0) | Err(_)) => break,
            Either4::First(Ok(count)) => {
                for &byte in bytes.get(..count).unwrap_or_default() {
                    let (message, then_close) = match connection.receive(byte, now_us(), &mut port)
                    {
                        Received::Nothing => continue,
                        Received::Send(message) => (message, false),
                        Received::SendAndClose(message) => (message, true),
                    };
                    if send(tx, &mut connection, &message).await.is_err() || then_close {
                        break 'stream;
                    }
                }
            }
            Either4::Second(WaitResult::Message(note)) => {
                if send(tx, &mut connection, &PeerMessage::Notify(note))
                    .await
                    .is_err()
                {
                    break;
                }
            }
            // Notifications this session was too slow for: the host falls back to Status.
            Either4::Second(WaitResult::Lagged(missed)) => {
                warn!("link: {} notifications dropped for a slow client", missed);
            }
            Either4::Third(()) => {
                info!("link: closing a connection that did not authenticate in time");
                break;
            }
            Either4::Fourth(()) => {
                info!("link: closing an unauthenticated connection for a newcomer");
                break;
            }
        }
    }
    connection.end(&mut port);
    info!("link: session ended");
}

/// Writes one message as one frame, within the connection's send deadline.
async fn send<W: Write>(
    tx: &mut W,
    connection: &mut Connection,
    message: &PeerMessage,
) -> Result<(), ()> {
    let mut frame = [0u8; MAX_FRAME];
    let len = connection.encode(message, &mut frame).map_err(|_| ())?;
    let bytes = frame.get(..len).ok_or(())?;
    let deadline = Instant::from_micros(connection.send_deadline_us(now_us()));
    match with_deadline(deadline, tx.write_all(bytes)).await {
        Ok(Ok(())) => Ok(()),
        Ok(Err(_)) => Err(()),
        Err(_) => {
            info!("link: closing a connection that does not take its replies");
            Err(())
        }
    }
}
