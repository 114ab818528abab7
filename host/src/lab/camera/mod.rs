//! Cameras: where a lab rig's images come from. Every backend returns a grayscale [`Frame`]
//! at the camera's own depth (8-bit, 12-bit data in 16-bit words, 16-bit); captures that
//! come back empty, unreadable or too small to hold a beam are errors that say which camera
//! and why. Saturation (pixels at the frame's own full scale) is reported so a user can
//! turn the exposure down.

mod command;
mod folder;
mod http;
mod image_file;
mod sim;
#[cfg(target_os = "linux")]
mod v4l2;

use async_trait::async_trait;
use optalign_optics::Frame;

pub use command::CommandCamera;
pub use folder::FolderCamera;
pub use http::HttpCamera;
pub use image_file::{decode_image, decode_image_bytes};
pub use sim::{SimCamera, SimScene, SimView};
#[cfg(target_os = "linux")]
pub use v4l2::{PIXEL_FORMATS, V4l2Camera, usable_format};

/// A source of camera frames.
#[async_trait]
pub trait Camera: Send {
    /// Takes one image (after any discarding and averaging the backend does).
    async fn capture(&mut self) -> anyhow::Result<Frame>;

    /// A short description for messages ("V4L2 /dev/video0", ...).
    fn describe(&self) -> String;
}

/// Smallest frame side that can hold a beam, px: the detector reads a frame's background
/// on cells of 16 px and its beams on blocks of 4.
pub const MIN_FRAME_SIDE_PX: u32 = 16;

/// `frame` from `source` when it can hold a beam: each side at least [`MIN_FRAME_SIDE_PX`].
pub fn large_enough(frame: Frame, source: &str) -> anyhow::Result<Frame> {
    let (width, height) = (frame.width(), frame.height());
    anyhow::ensure!(
        width >= MIN_FRAME_SIDE_PX && height >= MIN_FRAME_SIDE_PX,
        "{source} gave a frame of {width} x {height} px, too small to hold a beam \
         (each side needs at least {MIN_FRAME_SIDE_PX} px)"
    );
    Ok(frame)
}

/// Fraction of pixels at the frame's own full scale (255, 4095 or 65535).
pub fn saturated_fraction(frame: &Frame) -> f64 {
    let pixels = frame.pixels();
    if pixels.is_empty() {
        return 0.0;
    }
    let full = frame.full_scale();
    pixels.iter().filter(|&&p| p == full).count() as f64 / pixels.len() as f64
}

/// Logs a warning when more than 1 % of a frame is saturated.
pub fn report_saturation(camera: &str, frame: &Frame) {
    let fraction = saturated_fraction(frame);
    if fraction > 0.01 {
        tracing::warn!(
            camera,
            saturated_percent = format!("{:.1}", fraction * 100.0),
            "frame is saturated; lower the exposure or gain so beam centres stay measurable"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn saturation_counts_pixels_at_the_frames_own_full_scale() {
        let frame = Frame::new(4, 1, vec![255, 10, 255, 0]).unwrap();
        assert_eq!(saturated_fraction(&frame), 0.5);
        let sixteen = Frame::deep(4, 1, vec![u16::MAX; 4], u16::MAX).unwrap();
        assert_eq!(saturated_fraction(&sixteen), 1.0);
        let twelve = Frame::deep(4, 1, vec![4095, 4095, 255, 0], 4095).unwrap();
        assert_eq!(saturated_fraction(&twelve), 0.5);
        // 255 is no saturation in a deeper frame.
        let deep = Frame::deep(4, 1, vec![255, 255, 255, 0], 4095).unwrap();
        assert_eq!(saturated_fraction(&deep), 0.0);
    }

    #[test]
    fn frames_too_small_for_a_beam_are_refused() {
        let tiny = Frame::new(1, 1, vec![0]).unwrap();
        let error = large_enough(tiny, "test camera").unwrap_err().to_string();
        assert!(error.contains("1 x 1 px, too small"), "{error}");
        let thin = Frame::new(640, 8, vec![0; 640 * 8]).unwrap();
        assert!(large_enough(thin, "test camera").is_err());
        let fine = Frame::new(16, 16, vec![0; 256]).unwrap();
        assert!(large_enough(fine, "test camera").is_ok());
    }
}
