//! Protocol frames over any async byte stream (TCP socket, serial port, pseudo-terminal),
//! sealed or checked for seals on authenticated sessions.

use std::collections::VecDeque;
use std::io;
use std::sync::Mutex;

use optalign_protocol::seal::{Inbound, Sealer};
use optalign_protocol::{FrameDecoder, FrameError, MAX_FRAME, encode_frame, encode_sealed_frame};
use serde::Serialize;
use serde::de::DeserializeOwned;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// Encodes `message` as one frame and writes it whole.
pub async fn write_frame<W, T>(writer: &mut W, message: &T) -> io::Result<()>
where
    W: AsyncWrite + Unpin,
    T: Serialize,
{
    write_frame_sealed(writer, message, None).await
}

/// Encodes `message` as one frame, sealed by `sealer` if given, and writes it whole.
pub async fn write_frame_sealed<W, T>(
    writer: &mut W,
    message: &T,
    sealer: Option<&mut Sealer>,
) -> io::Result<()>
where
    W: AsyncWrite + Unpin,
    T: Serialize,
{
    let mut frame = [0u8; MAX_FRAME];
    let encoded = match sealer {
        Some(sealer) => encode_sealed_frame(message, sealer, &mut frame),
        None => encode_frame(message, &mut frame),
    };
    let len = encoded.map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e.to_string()))?;
    writer.write_all(&frame[..len]).await?;
    writer.flush().await
}

/// Reads frames of type `T` from a stream; bad frames come out as errors, in order.
pub struct FrameReader<R, T> {
    reader: R,
    decoder: FrameDecoder,
    ready: VecDeque<Result<T, FrameError>>,
    buf: Box<[u8; 1024]>,
}

impl<R: AsyncRead + Unpin, T: DeserializeOwned> FrameReader<R, T> {
    pub fn new(reader: R) -> Self {
        Self {
            reader,
            decoder: FrameDecoder::new(),
            ready: VecDeque::new(),
            buf: Box::new([0; 1024]),
        }
    }

    /// The next plain frame, or `None` at end of stream.
    pub async fn next(&mut self) -> io::Result<Option<Result<T, FrameError>>> {
        self.next_checked(&mut Inbound::plain()).await
    }

    /// The next frame, checked against `inbound` (see
    /// [`FrameDecoder::push_checked`]), or `None` at end of stream. Cancel safe: bytes
    /// read are kept for the next call.
    pub async fn next_checked(
        &mut self,
        inbound: &mut Inbound,
    ) -> io::Result<Option<Result<T, FrameError>>> {
        loop {
            if let Some(frame) = self.ready.pop_front() {
                return Ok(Some(frame));
            }
            let Some(len) = self.read().await? else {
                return Ok(None);
            };
            self.decode(len, inbound);
        }
    }

    /// Like [`next_checked`](Self::next_checked) with a check that another task updates
    /// (a client installs its session key while its reader waits); locked only to decode.
    pub async fn next_shared(
        &mut self,
        inbound: &Mutex<Inbound>,
    ) -> io::Result<Option<Result<T, FrameError>>> {
        loop {
            if let Some(frame) = self.ready.pop_front() {
                return Ok(Some(frame));
            }
            let Some(len) = self.read().await? else {
                return Ok(None);
            };
            let mut inbound = inbound.lock().unwrap_or_else(|e| e.into_inner());
            self.decode(len, &mut inbound);
        }
    }

    /// Reads what is there into the buffer: its length, or `None` at end of stream.
    async fn read(&mut self) -> io::Result<Option<usize>> {
        let len = self.reader.read(&mut self.buf[..]).await?;
        Ok((len > 0).then_some(len))
    }

    fn decode(&mut self, len: usize, inbound: &mut Inbound) {
        let ready = &mut self.ready;
        self.decoder
            .feed_checked(&self.buf[..len], inbound, |frame| ready.push_back(frame));
    }
}
