//! The camera frame: a grayscale image at the camera's own depth (8-bit, 12-bit data in 16-bit
//! words, or 16-bit), row-major, with PNG encoding and decoding of image files bounded in size
//! before anything is decoded.
//!
//! Analysis reads a frame in gray levels of an 8-bit frame ([`Frame::levels_per_count`]):
//! the same light is the same number at every depth, and deeper frames keep their fractions.

use std::io::Cursor;

use image::codecs::png::PngEncoder;
use image::{DynamicImage, ExtendedColorType, ImageEncoder, ImageFormat, ImageReader, Limits};
use thiserror::Error;

/// Full scale of an 8-bit frame.
pub const FULL_SCALE_8: u16 = u8::MAX as u16;
/// Full scale of 12-bit data in 16-bit words, as machine-vision cameras write it.
pub const FULL_SCALE_12: u16 = 4095;
/// Full scale of a 16-bit frame.
pub const FULL_SCALE_16: u16 = u16::MAX;

/// Largest image side, px: decoded from a file, or rendered from a scenario (whose per-row
/// noise table is sized to it, so rows never repeat each other's noise).
pub const MAX_SIDE_PX: u32 = 16384;
/// Most pixels decoded in one image (64 megapixels: a frame's analysis takes about 10 bytes
/// a pixel).
pub const MAX_PIXELS: u64 = 1 << 26;
/// Most memory the decoder may allocate for one image, bytes (64 megapixels of RGBA 8-bit,
/// or 32 megapixels of RGBA 16-bit).
pub const MAX_DECODE_BYTES: u64 = 1 << 28;

/// Why a frame could not be built, encoded or decoded.
#[derive(Debug, Error)]
pub enum FrameError {
    /// The pixel buffer does not hold width x height values.
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
    /// A pixel is above the full scale given, or the full scale is below 8 bits.
    #[error("pixel value {value} is above the frame's full scale {full_scale}")]
    Depth {
        /// The offending value (or the full scale itself when that is below 255).
        value: u16,
        /// The full scale given.
        full_scale: u16,
    },
    /// The image is larger than the decoder accepts (checked before decoding).
    #[error("image of {width} x {height} px is above the limit of {limit}")]
    TooLarge {
        /// Width in pixels, as the file's header says.
        width: u32,
        /// Height in pixels, as the file's header says.
        height: u32,
        /// The limit it breaks, in words.
        limit: String,
    },
    /// The codec failed.
    #[error("{0}")]
    Codec(#[from] image::ImageError),
}

/// One grayscale camera image: `pixels[y * width + x]`, x right, y down, values from 0 to
/// the frame's full scale (255 for 8-bit frames, 4095 for 12-bit data, 65535 for 16-bit).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Frame {
    width: u32,
    height: u32,
    full_scale: u16,
    pixels: Vec<u16>,
}

impl Frame {
    /// Wraps a row-major 8-bit pixel buffer of exactly `width * height` bytes.
    pub fn new(width: u32, height: u32, pixels: Vec<u8>) -> Result<Self, FrameError> {
        Self::deep(
            width,
            height,
            pixels.into_iter().map(u16::from).collect(),
            FULL_SCALE_8,
        )
    }

    /// Wraps a row-major buffer of `width * height` values from 0 to `full_scale` (at least
    /// 255).
    pub fn deep(
        width: u32,
        height: u32,
        pixels: Vec<u16>,
        full_scale: u16,
    ) -> Result<Self, FrameError> {
        let expected = width as usize * height as usize;
        if pixels.len() != expected {
            return Err(FrameError::Size {
                width,
                height,
                expected,
                got: pixels.len(),
            });
        }
        if full_scale < FULL_SCALE_8 {
            return Err(FrameError::Depth {
                value: full_scale,
                full_scale,
            });
        }
        if let Some(&value) = pixels.iter().find(|&&p| p > full_scale) {
            return Err(FrameError::Depth { value, full_scale });
        }
        Ok(Self {
            width,
            height,
            full_scale,
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

    /// The largest value a pixel can hold: where the sensor saturates.
    pub fn full_scale(&self) -> u16 {
        self.full_scale
    }

    /// Gray levels of an 8-bit frame per count of this one (1 for 8-bit frames).
    pub fn levels_per_count(&self) -> f32 {
        f32::from(FULL_SCALE_8) / f32::from(self.full_scale)
    }

    /// The row-major pixel buffer, in counts of the frame's own depth.
    pub fn pixels(&self) -> &[u16] {
        &self.pixels
    }

    /// The value at column `x`, row `y`, in counts of the frame's own depth.
    ///
    /// # Panics
    /// If `(x, y)` lies outside the frame.
    pub fn pixel(&self, x: u32, y: u32) -> u16 {
        assert!(
            x < self.width && y < self.height,
            "pixel ({x}, {y}) outside frame"
        );
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// The frame scaled to 8 bits (full scale to 255), for showing it.
    pub fn to_8bit(&self) -> Vec<u8> {
        if self.full_scale == FULL_SCALE_8 {
            return self.pixels.iter().map(|&p| p as u8).collect();
        }
        let scale = u32::from(self.full_scale);
        self.pixels
            .iter()
            .map(|&p| ((u32::from(p) * 255 + scale / 2) / scale) as u8)
            .collect()
    }

    /// Encodes the frame as a grayscale PNG at its own depth (8 or 16 bits).
    pub fn encode_png(&self) -> Result<Vec<u8>, FrameError> {
        let mut out = Vec::new();
        if self.full_scale == FULL_SCALE_8 {
            return self.encode_8bit_png();
        }
        let bytes: Vec<u8> = self.pixels.iter().flat_map(|p| p.to_ne_bytes()).collect();
        PngEncoder::new(&mut out).write_image(
            &bytes,
            self.width,
            self.height,
            ExtendedColorType::L16,
        )?;
        Ok(out)
    }

    /// Encodes the frame scaled to 8 bits as a grayscale PNG, for showing it.
    pub fn encode_8bit_png(&self) -> Result<Vec<u8>, FrameError> {
        let mut out = Vec::new();
        PngEncoder::new(&mut out).write_image(
            &self.to_8bit(),
            self.width,
            self.height,
            ExtendedColorType::L8,
        )?;
        Ok(out)
    }

    /// Decodes a PNG; colour images are converted to grayscale.
    pub fn decode_png(bytes: &[u8]) -> Result<Self, FrameError> {
        Self::decode(bytes, Some(ImageFormat::Png))
    }

    /// Decodes an image file's bytes (`format`, or guessed from the bytes when `None`), its
    /// size checked against `MAX_SIDE_PX`, `MAX_PIXELS` and `MAX_DECODE_BYTES` before
    /// decoding. Colour is converted to luminance. 8-bit images stay 8-bit; deeper ones become
    /// 16-bit frames, or 12-bit frames when no value exceeds 4095 (12-bit data in 16-bit
    /// words, as many machine-vision cameras write it).
    pub fn decode(bytes: &[u8], format: Option<ImageFormat>) -> Result<Self, FrameError> {
        let reader = match format {
            Some(format) => ImageReader::with_format(Cursor::new(bytes), format),
            None => ImageReader::new(Cursor::new(bytes))
                .with_guessed_format()
                .map_err(image::ImageError::IoError)?,
        };
        let mut decoder = reader.into_decoder()?;
        let (width, height) = image::ImageDecoder::dimensions(&decoder);
        let too_large = |limit: String| FrameError::TooLarge {
            width,
            height,
            limit,
        };
        if width.max(height) > MAX_SIDE_PX {
            return Err(too_large(format!("{MAX_SIDE_PX} px a side")));
        }
        if u64::from(width) * u64::from(height) > MAX_PIXELS {
            return Err(too_large(format!("{} megapixels", MAX_PIXELS >> 20)));
        }
        let mut limits = Limits::default();
        limits.max_image_width = Some(MAX_SIDE_PX);
        limits.max_image_height = Some(MAX_SIDE_PX);
        limits.max_alloc = Some(MAX_DECODE_BYTES);
        let decoded_bytes = image::ImageDecoder::total_bytes(&decoder);
        if decoded_bytes > MAX_DECODE_BYTES {
            return Err(too_large(format!(
                "{} MiB decoded (it needs {} MiB)",
                MAX_DECODE_BYTES >> 20,
                decoded_bytes >> 20
            )));
        }
        image::ImageDecoder::set_limits(&mut decoder, limits)?;
        let image = DynamicImage::from_decoder(decoder)?;
        let deep = image.color().bytes_per_pixel() / image.color().channel_count() > 1;
        if !deep {
            let gray = image.into_luma8();
            return Self::new(width, height, gray.into_raw());
        }
        let gray = image.into_luma16().into_raw();
        let top = gray.iter().copied().max().unwrap_or(0);
        let full_scale = if top <= FULL_SCALE_12 {
            FULL_SCALE_12
        } else {
            FULL_SCALE_16
        };
        Self::deep(width, height, gray, full_scale)
    }
}
