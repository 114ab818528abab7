//! Reading an image file written by a camera's own software into a grayscale frame at the
//! file's own depth, its size bounded before anything is decoded.

use std::path::Path;

use anyhow::Context;
use optalign_optics::Frame;

use super::large_enough;

/// Decodes PNG, JPEG or TIFF (colour is converted to luminance; 16-bit files stay 16-bit,
/// or 12-bit when no value exceeds 4095). Refuses images larger than the decoder's limits
/// (named in the error) before decoding them, and frames too small to hold a beam.
pub fn decode_image(path: &Path) -> anyhow::Result<Frame> {
    let bytes =
        std::fs::read(path).with_context(|| format!("cannot read image {}", path.display()))?;
    decode_image_bytes(&bytes, &path.display().to_string())
}

/// Decodes an image's bytes from `source` (a path or URL, for messages).
pub fn decode_image_bytes(bytes: &[u8], source: &str) -> anyhow::Result<Frame> {
    anyhow::ensure!(
        !bytes.is_empty(),
        "image {source} is empty (the camera wrote nothing)"
    );
    let frame = Frame::decode(bytes, None).map_err(|error| match error {
        optalign_optics::FrameError::TooLarge { .. } => {
            anyhow::anyhow!("image {source} refused: {error}")
        }
        _ => anyhow::anyhow!(
            "{source} is not a PNG, JPEG or TIFF image this camera can read: {error}"
        ),
    })?;
    large_enough(frame, &format!("image {source}"))
}

#[cfg(test)]
mod tests {
    use image::{ImageFormat, RgbImage};

    use super::*;

    /// A 16 x 16 colour ramp, and its luminance as `into_luma8` computes it.
    fn ramp() -> (RgbImage, Vec<u8>) {
        let colour = RgbImage::from_fn(16, 16, |x, y| {
            image::Rgb([(x * 16) as u8, (y * 16) as u8, 128])
        });
        let luma = image::DynamicImage::ImageRgb8(colour.clone())
            .into_luma8()
            .into_raw();
        (colour, luma)
    }

    /// `image` written by the `image` crate as `format` to a file named `name`.
    fn write(dir: &Path, name: &str, image: &RgbImage, format: ImageFormat) -> std::path::PathBuf {
        let path = dir.join(name);
        image.save_with_format(&path, format).unwrap();
        path
    }

    #[test]
    fn reads_jpeg_and_tiff_as_cameras_write_them() {
        let dir = tempfile::tempdir().unwrap();
        let (colour, luma) = ramp();

        // TIFF is lossless: exactly the luminance.
        let tiff = write(dir.path(), "a.tif", &colour, ImageFormat::Tiff);
        let frame = decode_image(&tiff).unwrap();
        assert_eq!((frame.width(), frame.height()), (16, 16));
        let wanted: Vec<u16> = luma.iter().map(|&v| u16::from(v)).collect();
        assert_eq!(frame.pixels(), wanted.as_slice());

        // JPEG is lossy: the luminance within a few levels.
        let jpeg = write(dir.path(), "a.jpg", &colour, ImageFormat::Jpeg);
        let frame = decode_image(&jpeg).unwrap();
        assert_eq!((frame.width(), frame.height()), (16, 16));
        let worst = frame
            .pixels()
            .iter()
            .zip(&luma)
            .map(|(&got, &want)| got.abs_diff(u16::from(want)))
            .max()
            .unwrap();
        assert!(worst <= 12, "JPEG luminance off by {worst}");
    }

    #[test]
    fn reads_png_and_refuses_empty_or_garbage_files() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("a.png");
        let frame = Frame::new(16, 16, (0..=255).collect()).unwrap();
        std::fs::write(&png, frame.encode_png().unwrap()).unwrap();
        assert_eq!(decode_image(&png).unwrap(), frame);
        let empty = dir.path().join("empty.png");
        std::fs::write(&empty, b"").unwrap();
        assert!(
            decode_image(&empty)
                .unwrap_err()
                .to_string()
                .contains("empty")
        );
        let junk = dir.path().join("junk.png");
        std::fs::write(&junk, b"not an image").unwrap();
        assert!(
            decode_image(&junk)
                .unwrap_err()
                .to_string()
                .contains("not a PNG")
        );
    }

    #[test]
    fn keeps_16_bit_and_12_bit_files_at_their_depth() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("deep.png");
        // A 16-bit ramp, and 12-bit data in 16-bit words (nothing above 4095).
        for (step, full_scale) in [(64, u16::MAX), (4, 4095)] {
            let values: Vec<u16> = (0..32u16 * 32).map(|i| i * step).collect();
            image::ImageBuffer::<image::Luma<u16>, _>::from_raw(32, 32, values.clone())
                .unwrap()
                .save(&path)
                .unwrap();
            let frame = decode_image(&path).unwrap();
            assert_eq!(frame.full_scale(), full_scale);
            assert_eq!(frame.pixels(), values.as_slice());
        }
    }

    #[test]
    fn refuses_huge_and_tiny_images_before_decoding_them() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("wide.png");
        image::GrayImage::new(20_000, 16).save(&path).unwrap();
        let error = decode_image(&path).unwrap_err().to_string();
        assert!(
            error.contains("above the limit of 16384 px a side"),
            "{error}"
        );
        let path = dir.path().join("huge.png");
        image::GrayImage::new(8200, 8200).save(&path).unwrap();
        let error = decode_image(&path).unwrap_err().to_string();
        assert!(
            error.contains("above the limit of 64 megapixels"),
            "{error}"
        );
        let tiny = dir.path().join("tiny.png");
        std::fs::write(
            &tiny,
            Frame::new(1, 1, vec![7]).unwrap().encode_png().unwrap(),
        )
        .unwrap();
        let error = decode_image(&tiny).unwrap_err().to_string();
        assert!(error.contains("too small to hold a beam"), "{error}");
    }
}
