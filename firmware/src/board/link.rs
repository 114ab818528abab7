//! Serving the protocol on one byte stream (a TCP connection, USB serial, UART0).
//!
//! Each connection is one [`Session`]: frames are decoded as they arrive and handed to the
//! core, each reply is written back at once, and the notifications the motion task
//! publishes are written in between. When the stream ends, the session ends with it,
//! which releases control of the motors if this connection held it.

use embassy_futures::select::{Either, select};
use embassy_sync::pubsub::WaitResult;
use embedded_io_async::{Read, Write};
use optalign_protocol::{FrameDecoder, FrameError, MAX_FRAME, PeerMessage, Request, encode_frame};

use super::log::{info, warn};
use super::motion::{LOOKAHEAD_US, NOTES, WAKE};
use super::rng::Rosc;
use super::{SharedCore, now_us};
use crate::session::{LinkKind, Session};

/// Sessions open at once: USB (or UART) plus the TCP connections.
pub const MAX_SESSIONS: usize = 4;

/// Serves `rx`/`tx` until the stream ends or fails.
pub async fn serve<R: Read, W: Write>(
    core: &'static SharedCore,
    link: LinkKind,
    rx: &mut R,
    tx: &mut W,
) {
    let Ok(mut notes) = NOTES.subscriber() else {
        warn!("link: no room for another session");
        return;
    };
    let mut session = Session::new(link);
    let mut decoder = FrameDecoder::new();
    let mut bytes = [0u8; 64];
    'stream: loop {
        match select(rx.read(&mut bytes), notes.next_message()).await {
            Either::First(Ok(0) | Err(_)) => break,
            Either::First(Ok(count)) => {
                for &byte in bytes.get(..count).unwrap_or_default() {
                    let Some(frame) = decoder.push::<Request>(byte) else {
                        continue;
                    };
                    let reply = respond(core, &mut session, frame);
                    WAKE.signal(());
                    if let Some(reply) = reply
                        && send(tx, &reply).await.is_err()
                    {
                        break 'stream;
                    }
                }
            }
            Either::Second(WaitResult::Message(note)) => {
                if send(tx, &PeerMessage::Notify(note)).await.is_err() {
                    break;
                }
            }
            // Notifications this session was too slow for: the host falls back to Status.
            Either::Second(WaitResult::Lagged(missed)) => {
                warn!("link: {} notifications dropped for a slow client", missed);
            }
        }
    }
    core.lock(|cell| cell.borrow_mut().end_session(&mut session));
    info!("link: session ended");
}

/// Hands one decoded frame (or the reason it could not be decoded) to the core.
fn respond(
    core: &SharedCore,
    session: &mut Session,
    frame: Result<Request, FrameError>,
) -> Option<PeerMessage> {
    let mut reply = None;
    core.lock(|cell| {
        let mut core = cell.borrow_mut();
        let mut out = |message| reply = Some(message);
        match frame {
            // At the lookahead horizon, where the motion task keeps the core's clock: a
            // move planned now starts after everything already queued, and its first pin
            // change is queued ahead of its time like every later one.
            Ok(request) => core.handle(
                session,
                &request,
                now_us() + LOOKAHEAD_US,
                &mut Rosc,
                &mut out,
            ),
            Err(error) => core.link_error(error, &mut out),
        }
    });
    reply
}

/// Writes one message as one frame.
async fn send<W: Write>(tx: &mut W, message: &PeerMessage) -> Result<(), ()> {
    let mut frame = [0u8; MAX_FRAME];
    let len = encode_frame(message, &mut frame).map_err(|_| ())?;
    let bytes = frame.get(..len).ok_or(())?;
    tx.write_all(bytes).await.map_err(|_| ())
}
