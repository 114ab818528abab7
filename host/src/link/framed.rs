//! Protocol frames over any async byte stream (TCP socket, serial port, pseudo-terminal).

use std::collections::VecDeque;
use std::io;

use optalign_protocol::{FrameDecoder, FrameError, MAX_FRAME, encode_frame};
use serde::Serialize;
use serde::de::DeserializeOwned;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

/// Encodes `message` as one frame and writes it whole.
pub async fn write_frame<W, T>(writer: &mut W, message: &T) -> io::Result<()>
where
    W: AsyncWrite + Unpin,
    T: Serialize,
{
    let mut frame = [0u8; MAX_FRAME];
    let len = encode_frame(message, &mut frame)
        .map_err(|e| io::Error::new(io::ErrorKind::InvalidInput, e.to_string()))?;
    writer.write_all(&frame[..len]).await?;
    writer.flush().await
}

/// Reads frames of type `T` from a stream; bad frames come out as errors, in order.
pub struct FrameReader<R, T> {
    reader: R,
    decoder: FrameDecoder,
    ready: VecDeque<Result<T, FrameError>>,
}

impl<R: AsyncRead + Unpin, T: DeserializeOwned> FrameReader<R, T> {
    pub fn new(reader: R) -> Self {
        Self {
            reader,
            decoder: FrameDecoder::new(),
            ready: VecDeque::new(),
        }
    }

    /// The next frame, or `None` at end of stream.
    pub async fn next(&mut self) -> io::Result<Option<Result<T, FrameError>>> {
        let mut buf = [0u8; 1024];
        loop {
            if let Some(frame) = self.ready.pop_front() {
                return Ok(Some(frame));
            }
            let n = self.reader.read(&mut buf).await?;
            if n == 0 {
                return Ok(None);
            }
            let ready = &mut self.ready;
            self.decoder.feed(&buf[..n], |frame| ready.push_back(frame));
        }
    }
}
