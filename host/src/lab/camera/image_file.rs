//! Reading an image file written by a camera's own software into a grayscale frame.

use std::path::Path;

use anyhow::Context;
use optalign_optics::Frame;

/// Decodes PNG, JPEG or TIFF (colour is converted to luminance).
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
    let image = image::load_from_memory(bytes)
        .with_context(|| format!("{source} is not a PNG, JPEG or TIFF image"))?
        .into_luma8();
    let (width, height) = image.dimensions();
    anyhow::ensure!(width > 0 && height > 0, "image {source} has no pixels");
    Ok(Frame::new(width, height, image.into_raw())?)
}

#[cfg(test)]
mod tests {
    use image::{ImageFormat, RgbImage};

    use super::*;

    /// A 16 x 8 colour ramp, and its luminance as `into_luma8` computes it.
    fn ramp() -> (RgbImage, Vec<u8>) {
        let colour = RgbImage::from_fn(16, 8, |x, y| {
            image::Rgb([(x * 16) as u8, (y * 32) as u8, 128])
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
        assert_eq!((frame.width(), frame.height()), (16, 8));
        assert_eq!(frame.pixels(), luma.as_slice());

        // JPEG is lossy: the luminance within a few levels.
        let jpeg = write(dir.path(), "a.jpg", &colour, ImageFormat::Jpeg);
        let frame = decode_image(&jpeg).unwrap();
        assert_eq!((frame.width(), frame.height()), (16, 8));
        let worst = frame
            .pixels()
            .iter()
            .zip(&luma)
            .map(|(&got, &want)| got.abs_diff(want))
            .max()
            .unwrap();
        assert!(worst <= 12, "JPEG luminance off by {worst}");
    }

    #[test]
    fn reads_png_and_refuses_empty_or_garbage_files() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("a.png");
        let frame = Frame::new(3, 2, vec![0, 50, 100, 150, 200, 250]).unwrap();
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
}
