//! Serving the protocol on one byte stream (a TCP connection, USB serial, UART0).
//!
//! Each connection is one [`Session`]: frames are decoded as they arrive and handed to the
//! core, each reply is written back at once, and the notifications the motion task
//! publishes are written in between. When the stream ends, the session ends with it,
//! which releases control of the motors if this connection held it.
//!
//! Frames are checked against the session (sealed only, once authenticated), and once the
//! session authenticated every frame written to it is sealed, notifications included. A
//! network connection that has not authenticated is closed when its session says so
//! ([`Session::close_at_us`]): idle for a few seconds, or on the reserved slot too long.

use embassy_futures::select::{Either3, select3};
use embassy_sync::pubsub::WaitResult;
use embassy_time::{Instant, Timer};
use embedded_io_async::{Read, Write};
use optalign_protocol::seal::Sealer;
use optalign_protocol::{
    FrameDecoder, FrameError, MAX_FRAME, PeerMessage, Request, encode_frame, encode_sealed_frame,
};

use super::log::{info, warn};
use super::motion::{LOOKAHEAD_US, NOTES, WAKE};
use super::rng::Nonces;
use super::{SharedCore, now_us};
use crate::session::{LinkKind, Session};

/// Sessions open at once: USB (or UART) plus the TCP connections.
pub const MAX_SESSIONS: usize = 4;

/// Serves `rx`/`tx` until the stream ends, fails or is closed as an idle stranger. On a
/// `reserved` slot the session may only authenticate (or stop) until it has.
pub async fn serve<R: Read, W: Write>(
    core: &'static SharedCore,
    link: LinkKind,
    reserved: bool,
    rx: &mut R,
    tx: &mut W,
) {
    let Ok(mut notes) = NOTES.subscriber() else {
        warn!("link: no room for another session");
        return;
    };
    let mut session = Session::opened(link, now_us());
    if reserved {
        session.keep_for_authentication();
    }
    let mut sealer: Option<Sealer> = None;
    let mut decoder = FrameDecoder::new();
    let mut bytes = [0u8; 64];
    'stream: loop {
        let close = session
            .close_at_us()
            .map_or(Instant::MAX, Instant::from_micros);
        match select3(rx.read(&mut bytes), notes.next_message(), Timer::at(close)).await {
            Either3::First(Ok(0) | Err(_)) => break,
            Either3::First(Ok(count)) => {
                for &byte in bytes.get(..count).unwrap_or_default() {
                    let Some(frame) = decoder.push_checked::<Request>(byte, session.inbound())
                    else {
                        continue;
                    };
                    if frame.is_ok() {
                        session.heard(now_us());
                    }
                    let reply = respond(core, &mut session, frame);
                    WAKE.signal(());
                    if let Some(fresh) = session.take_sealer() {
                        sealer = Some(fresh);
                    }
                    if let Some(reply) = reply
                        && send(tx, &reply, sealer.as_mut()).await.is_err()
                    {
                        break 'stream;
                    }
                }
            }
            Either3::Second(WaitResult::Message(note)) => {
                if send(tx, &PeerMessage::Notify(note), sealer.as_mut())
                    .await
                    .is_err()
                {
                    break;
                }
            }
            // Notifications this session was too slow for: the host falls back to Status.
            Either3::Second(WaitResult::Lagged(missed)) => {
                warn!("link: {} notifications dropped for a slow client", missed);
            }
            Either3::Third(()) => {
                info!("link: closing a connection that did not authenticate in time");
                break;
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
                &mut Nonces,
                &mut out,
            ),
            Err(error) => core.link_error(error, &mut out),
        }
    });
    reply
}

/// Writes one message as one frame, sealed once the session authenticated.
async fn send<W: Write>(
    tx: &mut W,
    message: &PeerMessage,
    sealer: Option<&mut Sealer>,
) -> Result<(), ()> {
    let mut frame = [0u8; MAX_FRAME];
    let len = match sealer {
        Some(sealer) => encode_sealed_frame(message, sealer, &mut frame),
        None => encode_frame(message, &mut frame),
    }
    .map_err(|_| ())?;
    let bytes = frame.get(..len).ok_or(())?;
    tx.write_all(bytes).await.map_err(|_| ())
}
