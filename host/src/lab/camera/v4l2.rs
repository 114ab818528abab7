//! The V4L2 camera: a USB or CSI camera on Linux with auto exposure and auto gain switched
//! off, so brightness means something, stale frames discarded after every move and
//! optional averaging. Frames are read at the camera's own depth: 16-bit (`Y16 `) and
//! 12-bit (`Y12 `, in 16-bit words) grayscale when the camera offers them, else 8-bit
//! (`GREY`, or the luma of `YUYV`). The ioctls are `linuxvideo`'s, plain Rust: nothing is
//! generated at build time, so every Linux build has this camera. Capture runs on a
//! blocking thread.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{Context, bail};
use async_trait::async_trait;
use linuxvideo::controls::Cid;
use linuxvideo::format::{Format, PixFormat, PixelFormat};
use linuxvideo::stream::ReadStream;
use linuxvideo::{BufType, Device};
use optalign_optics::Frame;

use super::{Camera, large_enough, report_saturation};

const EXPOSURE_MANUAL: i32 = 1;

/// The pixel formats read, deepest first, with their full scale.
pub const PIXEL_FORMATS: [(&[u8; 4], u16); 4] = [
    (b"Y16 ", u16::MAX),
    (b"Y12 ", 4095),
    (b"GREY", 255),
    (b"YUYV", 255),
];

/// How one frame's bytes are laid out.
#[derive(Clone, Copy, Debug)]
struct Layout {
    width: u32,
    height: u32,
    /// Bytes from one row to the next (rows may be padded).
    stride: usize,
    fourcc: [u8; 4],
    full_scale: u16,
}

struct Capturer {
    stream: ReadStream,
    layout: Layout,
}

pub struct V4l2Camera {
    path: PathBuf,
    capturer: Arc<Mutex<Capturer>>,
    discard: u32,
    average: u32,
}

/// The deepest of [`PIXEL_FORMATS`] that `device` offers, with its full scale.
pub fn usable_format(device: &Device) -> Option<(PixelFormat, u16)> {
    let offered: Vec<PixelFormat> = device
        .formats(BufType::VIDEO_CAPTURE)
        .filter_map(Result::ok)
        .map(|format| format.pixel_format())
        .collect();
    PIXEL_FORMATS
        .iter()
        .map(|&(fourcc, full)| (PixelFormat::from_fourcc(*fourcc), full))
        .find(|(format, _)| offered.contains(format))
}

impl V4l2Camera {
    pub fn open(
        path: &Path,
        exposure: i64,
        gain: i64,
        discard: u32,
        average: u32,
    ) -> anyhow::Result<Self> {
        let mut device =
            Device::open(path).with_context(|| format!("cannot open camera {}", path.display()))?;
        let exposure = i32::try_from(exposure)
            .with_context(|| format!("camera.exposure {exposure} is beyond what V4L2 takes"))?;
        let gain = i32::try_from(gain)
            .with_context(|| format!("camera.gain {gain} is beyond what V4L2 takes"))?;
        for (id, value, name) in [
            (Cid::EXPOSURE_AUTO, EXPOSURE_MANUAL, "manual exposure"),
            (Cid::EXPOSURE_ABSOLUTE, exposure, "exposure"),
            (Cid::AUTOGAIN, 0, "auto gain off"),
            (Cid::GAIN, gain, "gain"),
        ] {
            if let Err(error) = device.write_control_raw(id, value) {
                tracing::warn!(camera = %path.display(), %error, "cannot set {name}; brightness may drift");
            }
        }
        let Some((pixel_format, full_scale)) = usable_format(&device) else {
            bail!(
                "camera {} offers none of Y16, Y12, GREY or YUYV frames",
                path.display()
            );
        };
        // Keep the size the camera is set to; change only the pixel format.
        let (width, height) = match device.format(BufType::VIDEO_CAPTURE) {
            Ok(Format::VideoCapture(current)) => (current.width(), current.height()),
            _ => (u32::MAX, u32::MAX),
        };
        let capture = device
            .video_capture(PixFormat::new(width, height, pixel_format))
            .with_context(|| format!("camera {} refused its pixel format", path.display()))?;
        let negotiated = capture.format();
        let layout = Layout {
            width: negotiated.width(),
            height: negotiated.height(),
            stride: negotiated.bytes_per_line() as usize,
            fourcc: negotiated.pixel_format().as_fourcc(),
            full_scale,
        };
        if layout.fourcc != pixel_format.as_fourcc() {
            bail!(
                "camera {} answered {:?} frames when asked for {:?}",
                path.display(),
                String::from_utf8_lossy(&layout.fourcc),
                String::from_utf8_lossy(&pixel_format.as_fourcc())
            );
        }
        let stream = capture
            .into_stream()
            .with_context(|| format!("cannot start streaming from {}", path.display()))?;
        Ok(Self {
            path: path.to_owned(),
            capturer: Arc::new(Mutex::new(Capturer { stream, layout })),
            discard,
            average,
        })
    }
}

/// One frame's luminance in counts of the camera's depth, from the bytes of a buffer.
fn luminance(bytes: &[u8], layout: &Layout) -> anyhow::Result<Vec<u16>> {
    let (width, height) = (layout.width as usize, layout.height as usize);
    let per_pixel = match &layout.fourcc {
        b"GREY" => 1,
        _ => 2,
    };
    let stride = layout.stride.max(width * per_pixel);
    if bytes.len() < stride * height.saturating_sub(1) + width * per_pixel {
        bail!(
            "the camera returned a short frame ({} bytes for {width} x {height} px)",
            bytes.len()
        );
    }
    let mut luma = Vec::with_capacity(width * height);
    for row in bytes.chunks(stride).take(height) {
        let row = &row[..width * per_pixel];
        match &layout.fourcc {
            b"GREY" => luma.extend(row.iter().map(|&v| u16::from(v))),
            // Y U Y V: the luma is every other byte.
            b"YUYV" => luma.extend(row.iter().step_by(2).map(|&v| u16::from(v))),
            _ => luma.extend(
                row.chunks_exact(2)
                    .map(|pair| u16::from_le_bytes([pair[0], pair[1]]).min(layout.full_scale)),
            ),
        }
    }
    Ok(luma)
}

impl Capturer {
    fn grab(&mut self) -> anyhow::Result<Vec<u16>> {
        let layout = self.layout;
        self.stream
            .dequeue(|buffer| {
                luminance(&buffer, &layout).map_err(|e| std::io::Error::other(e.to_string()))
            })
            .map_err(anyhow::Error::from)
    }
}

#[async_trait]
impl Camera for V4l2Camera {
    async fn capture(&mut self) -> anyhow::Result<Frame> {
        let capturer = self.capturer.clone();
        let (discard, average) = (self.discard, self.average);
        let frame = tokio::task::spawn_blocking(move || -> anyhow::Result<Frame> {
            let mut capturer = capturer.lock().unwrap_or_else(|e| e.into_inner());
            for _ in 0..discard {
                capturer.grab()?;
            }
            let mut sum: Vec<u32> = Vec::new();
            for _ in 0..average {
                let luma = capturer.grab()?;
                if sum.is_empty() {
                    sum = vec![0; luma.len()];
                }
                for (s, v) in sum.iter_mut().zip(luma) {
                    *s += u32::from(v);
                }
            }
            let pixels = sum.iter().map(|s| (s / average) as u16).collect();
            let layout = capturer.layout;
            Ok(Frame::deep(
                layout.width,
                layout.height,
                pixels,
                layout.full_scale,
            )?)
        })
        .await??;
        let frame = large_enough(frame, &self.describe())?;
        report_saturation(&self.describe(), &frame);
        Ok(frame)
    }

    fn describe(&self) -> String {
        format!("V4L2 {}", self.path.display())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn layout(fourcc: &[u8; 4], stride: usize, full_scale: u16) -> Layout {
        Layout {
            width: 2,
            height: 2,
            stride,
            fourcc: *fourcc,
            full_scale,
        }
    }

    #[test]
    fn frames_are_read_at_their_depth_past_row_padding() {
        // GREY rows padded to 4 bytes.
        let grey = luminance(&[1, 2, 0, 0, 3, 4, 0, 0], &layout(b"GREY", 4, 255)).unwrap();
        assert_eq!(grey, [1, 2, 3, 4]);
        // YUYV: the luma bytes only.
        let yuyv = luminance(&[10, 99, 20, 98, 30, 97, 40, 96], &layout(b"YUYV", 4, 255)).unwrap();
        assert_eq!(yuyv, [10, 20, 30, 40]);
        // Y12 in 16-bit little-endian words, clamped to 4095.
        let y12 = luminance(
            &[0xff, 0x0f, 0x00, 0x10, 0x01, 0x00, 0x02, 0x00],
            &layout(b"Y12 ", 4, 4095),
        )
        .unwrap();
        assert_eq!(y12, [4095, 4095, 1, 2]);
        let short = luminance(&[1, 2, 3], &layout(b"GREY", 2, 255));
        assert!(short.unwrap_err().to_string().contains("short frame"));
    }
}
