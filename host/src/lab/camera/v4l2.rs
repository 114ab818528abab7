//! The V4L2 camera (feature `v4l2`): a USB or CSI camera on Linux with auto exposure and
//! auto gain switched off, so brightness means something, stale frames discarded after
//! every move and optional averaging. Frames are read at the camera's own depth: 16-bit
//! (`Y16 `) and 12-bit (`Y12 `, in 16-bit words) grayscale when the camera offers them,
//! else 8-bit (`GREY`, or the luma of `YUYV`). Capture runs on a blocking thread.

use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::Frame;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::{Camera, large_enough, report_saturation};

const EXPOSURE_AUTO: u32 = 0x009a_0901;
const EXPOSURE_MANUAL: i64 = 1;
const EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
const AUTOGAIN: u32 = 0x0098_0912;
const GAIN: u32 = 0x0098_0913;

/// The pixel formats read, deepest first, with their full scale.
const PIXEL_FORMATS: [(&[u8; 4], u16); 4] = [
    (b"Y16 ", u16::MAX),
    (b"Y12 ", 4095),
    (b"GREY", 255),
    (b"YUYV", 255),
];

struct Capturer {
    stream: Stream<'static>,
    width: u32,
    height: u32,
    fourcc: FourCC,
}

pub struct V4l2Camera {
    path: PathBuf,
    capturer: Arc<Mutex<Capturer>>,
    discard: u32,
    average: u32,
}

impl V4l2Camera {
    pub fn open(
        path: &Path,
        exposure: i64,
        gain: i64,
        discard: u32,
        average: u32,
    ) -> anyhow::Result<Self> {
        let device = Device::with_path(path)
            .with_context(|| format!("cannot open camera {}", path.display()))?;
        for (id, value, name) in [
            (EXPOSURE_AUTO, EXPOSURE_MANUAL, "manual exposure"),
            (EXPOSURE_ABSOLUTE, exposure, "exposure"),
            (AUTOGAIN, 0, "auto gain off"),
            (GAIN, gain, "gain"),
        ] {
            if let Err(error) = device.set_control(Control {
                id,
                value: Value::Integer(value),
            }) {
                tracing::warn!(camera = %path.display(), %error, "cannot set {name}; brightness may drift");
            }
        }
        let mut format = device.format()?;
        for (fourcc, _) in PIXEL_FORMATS {
            format.fourcc = FourCC::new(fourcc);
            if let Ok(actual) = device.set_format(&format)
                && actual.fourcc == format.fourcc
            {
                format = actual;
                break;
            }
        }
        if !PIXEL_FORMATS
            .iter()
            .any(|(fourcc, _)| format.fourcc == FourCC::new(fourcc))
        {
            bail!(
                "camera {} offers none of Y16, Y12, GREY or YUYV frames (it offers {})",
                path.display(),
                format.fourcc
            );
        }
        // The stream borrows the device for as long as it lives, which is the process.
        let device = Box::leak(Box::new(device));
        let stream = Stream::with_buffers(device, Type::VideoCapture, 4)
            .with_context(|| format!("cannot start streaming from {}", path.display()))?;
        Ok(Self {
            path: path.to_owned(),
            capturer: Arc::new(Mutex::new(Capturer {
                stream,
                width: format.width,
                height: format.height,
                fourcc: format.fourcc,
            })),
            discard,
            average,
        })
    }
}

impl Capturer {
    /// The full scale of the frames read.
    fn full_scale(&self) -> u16 {
        PIXEL_FORMATS
            .iter()
            .find(|(fourcc, _)| self.fourcc == FourCC::new(fourcc))
            .map_or(255, |&(_, full)| full)
    }

    /// One frame's luminance, in counts of the camera's depth.
    fn grab(&mut self) -> anyhow::Result<Vec<u16>> {
        let full_scale = self.full_scale();
        let yuyv = self.fourcc == FourCC::new(b"YUYV");
        let pixels = (self.width * self.height) as usize;
        let (buffer, _) = self.stream.next()?;
        let luma: Vec<u16> = if full_scale > 255 {
            buffer
                .chunks_exact(2)
                .take(pixels)
                .map(|pair| u16::from_le_bytes([pair[0], pair[1]]).min(full_scale))
                .collect()
        } else if yuyv {
            buffer
                .iter()
                .step_by(2)
                .take(pixels)
                .map(|&v| u16::from(v))
                .collect()
        } else {
            buffer.iter().take(pixels).map(|&v| u16::from(v)).collect()
        };
        if luma.len() != pixels {
            bail!(
                "the camera returned a short frame ({} of {pixels} pixels)",
                luma.len()
            );
        }
        Ok(luma)
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
            Ok(Frame::deep(
                capturer.width,
                capturer.height,
                pixels,
                capturer.full_scale(),
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
