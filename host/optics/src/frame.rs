//! The camera frame: an 8-bit grayscale image, row-major, with PNG encoding and decoding.

use std::io::Cursor;

use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder, ImageFormat};
use thiserror::Error;

/// Why a frame could not be built, encoded or decoded.
#[derive(Debug, Error)]
pub enum FrameError {
    /// The pixel buffer does not hold width x height bytes.
    #[error("frame of {width}x{height} needs {expected} pixels, got {got}")]
    Size {
        /// Width in pixels.
        width: u32,
        /// Height in pixels.
        height: u32,
        /// width x height.
        expected: usize,
        /// Length of the buffer given.
        got: usize,
    },
    /// The PNG codec failed.
    #[error("png: {0}")]
    Png(#[from] image::ImageError),
}

/// One grayscale camera image: `pixels[y * width + x]`, x right, y down.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    width: u32,
    height: u32,
    pixels: Vec<u8>,
}

impl Frame {
    /// Wraps a row-major pixel buffer of exactly `width * height` bytes.
    pub fn new(width: u32, height: u32, pixels: Vec<u8>) -> Result<Self, FrameError> {
        let expected = width as usize * height as usize;
        if pixels.len() != expected {
            return Err(FrameError::Size {
                width,
                height,
                expected,
                got: pixels.len(),
            });
        }
        Ok(Self {
            width,
            height,
            pixels,
        })
    }

    /// Width in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The row-major pixel buffer.
    pub fn pixels(&self) -> &[u8] {
        &self.pixels
    }

    /// The gray level at column `x`, row `y`.
    ///
    /// # Panics
    /// If `(x, y)` lies outside the frame.
    pub fn pixel(&self, x: u32, y: u32) -> u8 {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside frame"
        );
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// Encodes the frame as an 8-bit grayscale PNG.
    pub fn encode_png(&self) -> Result<Vec<u8>, FrameError> {
        let mut out = Vec::new();
        PngEncoder::new(&mut out).write_image(
            &self.pixels,
            self.width,
            self.height,
            ExtendedColorType::L8,
        )?;
        Ok(out)
    }

    /// Decodes a PNG; colour images are converted to grayscale.
    pub fn decode_png(bytes: &[u8]) -> Result<Self, FrameError> {
        let image = image::ImageReader::with_format(Cursor::new(bytes), ImageFormat::Png)
            .decode()?
            .into_luma8();
        let (width, height) = image.dimensions();
        Self::new(width, height, image.into_raw())
    }
}
