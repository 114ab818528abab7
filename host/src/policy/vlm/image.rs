//! Camera frames as the model receives them: downscaled so the longer side is at most a
//! configured number of pixels (an area-weighted filter, which also averages sensor noise),
//! encoded as grayscale PNG and wrapped in a base64 data URL.

use base64::Engine;
use base64::engine::general_purpose::STANDARD;
use image::imageops::FilterType;
use image::{DynamicImage, GrayImage};
use optalign_optics::Frame;

/// The default longest side sent to a model, px. Keeps the features each task needs:
/// Michelson beams (radius 115-130 px on 1920 x 1080) stay about 60 px across in radius and
/// their 42 px fringes stay resolved; the cavity's dim secondary (radius 35 px on 1280 x
/// 1024) keeps a 28 px radius; relay frames (640 x 480, 2.5 px speckle grains) go unscaled.
pub const DEFAULT_MAX_SIDE: u32 = 1024;

/// One frame ready for a chat message.
#[derive(Clone, Debug)]
pub struct PreparedImage {
    pub data_url: String,
    pub width: u32,
    pub height: u32,
}

/// The size of a `width x height` frame once its longer side is at most `max_side`.
pub fn scaled_size(width: u32, height: u32, max_side: u32) -> (u32, u32) {
    let longest = width.max(height);
    if longest <= max_side {
        return (width, height);
    }
    let scale = f64::from(max_side) / f64::from(longest);
    let shrink = |side: u32| ((f64::from(side) * scale).round() as u32).clamp(1, max_side);
    (shrink(width), shrink(height))
}

/// Downscales (when needed) and encodes a frame, scaled to 8 bits.
pub fn prepare(frame: &Frame, max_side: u32) -> Result<PreparedImage, String> {
    let (width, height) = scaled_size(frame.width(), frame.height(), max_side);
    let frame = if (width, height) == (frame.width(), frame.height()) {
        frame.clone()
    } else {
        let source = GrayImage::from_raw(frame.width(), frame.height(), frame.to_8bit())
            .ok_or("the frame's pixel buffer does not match its size")?;
        // Through `DynamicImage`, so the filter runs as compiled (optimised) in `image`.
        let small =
            DynamicImage::ImageLuma8(source).resize_exact(width, height, FilterType::Triangle);
        Frame::new(width, height, small.into_luma8().into_raw()).map_err(|e| e.to_string())?
    };
    let png = frame.encode_8bit_png().map_err(|e| e.to_string())?;
    Ok(PreparedImage {
        data_url: format!("data:image/png;base64,{}", STANDARD.encode(png)),
        width,
        height,
    })
}

/// Decodes a `data:image/png;base64,` URL back into a frame.
pub fn decode_data_url(url: &str) -> Result<Frame, String> {
    let encoded = url
        .strip_prefix("data:image/png;base64,")
        .ok_or("the image is not a data:image/png;base64 URL")?;
    let bytes = STANDARD
        .decode(encoded)
        .map_err(|e| format!("the image's base64 does not decode: {e}"))?;
    Frame::decode_png(&bytes).map_err(|e| format!("the image is not a readable PNG: {e}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_keep_the_aspect_and_never_grow() {
        assert_eq!(scaled_size(1920, 1080, 1024), (1024, 576));
        assert_eq!(scaled_size(1280, 1024, 1024), (1024, 819));
        assert_eq!(scaled_size(640, 480, 1024), (640, 480));
        assert_eq!(scaled_size(1080, 1920, 512), (288, 512));
    }

    #[test]
    fn a_downscaled_frame_keeps_a_bright_spot_where_it_was() {
        let (width, height) = (400, 200);
        let pixels = (0..width * height)
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let d2 = (x as f64 - 300.0).powi(2) + (y as f64 - 50.0).powi(2);
                (200.0 * (-d2 / 200.0).exp()) as u8
            })
            .collect();
        let frame = Frame::new(width, height, pixels).unwrap();
        let image = prepare(&frame, 100).unwrap();
        assert_eq!((image.width, image.height), (100, 50));
        let small = decode_data_url(&image.data_url).unwrap();
        let brightest = (0..small.height())
            .flat_map(|y| (0..small.width()).map(move |x| (x, y)))
            .max_by_key(|&(x, y)| small.pixel(x, y))
            .unwrap();
        assert!(
            (brightest.0 as i32 - 75).abs() <= 1 && (brightest.1 as i32 - 12).abs() <= 1,
            "{brightest:?}"
        );
        let unscaled = prepare(&frame, 400).unwrap();
        assert_eq!(decode_data_url(&unscaled.data_url).unwrap(), frame);
        assert!(decode_data_url("data:image/jpeg;base64,AAAA").is_err());
    }
}
