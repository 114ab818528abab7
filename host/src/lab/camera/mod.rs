//! Cameras: where a lab rig's images come from. Every backend returns an 8-bit grayscale
//! [`Frame`]; captures that come back empty or unreadable are errors that say which
//! camera and why. Saturation is reported so a user can turn the exposure down.

mod command;
mod folder;
mod http;
mod image_file;
mod sim;
#[cfg(feature = "v4l2")]
mod v4l2;

use async_trait::async_trait;
use optalign_optics::Frame;

pub use command::CommandCamera;
pub use folder::FolderCamera;
pub use http::HttpCamera;
pub use image_file::{decode_image, decode_image_bytes};
pub use sim::{SimCamera, SimScene, SimView};
#[cfg(feature = "v4l2")]
pub use v4l2::V4l2Camera;

/// A source of camera frames.
#[async_trait]
pub trait Camera: Send {
    /// Takes one image (after any discarding and averaging the backend does).
    async fn capture(&mut self) -> anyhow::Result<Frame>;

    /// A short description for messages ("V4L2 /dev/video0", ...).
    fn describe(&self) -> String;
}

/// Fraction of pixels at full scale (255).
pub fn saturated_fraction(frame: &Frame) -> f64 {
    let pixels = frame.pixels();
    if pixels.is_empty() {
        return 0.0;
    }
    pixels.iter().filter(|&&p| p == u8::MAX).count() as f64 / pixels.len() as f64
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
    fn saturation_counts_full_scale_pixels() {
        let frame = Frame::new(4, 1, vec![255, 10, 255, 0]).unwrap();
        assert_eq!(saturated_fraction(&frame), 0.5);
    }
}
