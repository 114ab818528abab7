//! The frames the page asks for: the newest frame in memory, older ones from the run
//! folder's `frames/NNNN.png`. A frame is encoded and searched for beams only when a page
//! asks for it, off the run's path, and only the last one asked for is kept: a slow browser
//! skips frames instead of queuing them.

use std::path::PathBuf;
use std::sync::{Arc, Mutex};

use anyhow::Context;
use optalign_optics::Frame;
use serde::Serialize;

use crate::imaging::{Picture, find_beams};

/// A frame ready for the page: the PNG and the beams the detector finds in it.
#[derive(Clone, Debug)]
pub struct ShownFrame {
    pub evaluation: usize,
    pub png: Arc<Vec<u8>>,
    pub beams: Arc<Detections>,
}

/// What the beam detector found in a frame, px (x right, y down).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Detections {
    pub width: u32,
    pub height: u32,
    pub beams: Vec<DetectedBeam>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct DetectedBeam {
    pub x: f64,
    pub y: f64,
    pub radius: f64,
}

impl Detections {
    pub fn of(frame: &Frame) -> Self {
        let beams = find_beams(&Picture::new(frame))
            .into_iter()
            .map(|beam| DetectedBeam {
                x: beam.centre[0],
                y: beam.centre[1],
                radius: beam.size(),
            })
            .collect();
        Self {
            width: frame.width(),
            height: frame.height(),
            beams,
        }
    }
}

/// The newest frame, the folder of saved ones, and the last frame shown.
#[derive(Default)]
pub struct FrameStore {
    state: Mutex<StoreState>,
}

#[derive(Default)]
struct StoreState {
    newest: Option<(usize, Arc<Frame>)>,
    folder: Option<PathBuf>,
    shown: Option<ShownFrame>,
}

impl FrameStore {
    /// A store that reads every frame from a run folder's `frames/`.
    pub fn from_folder(folder: PathBuf) -> Self {
        let store = Self::default();
        store.lock().folder = Some(folder);
        store
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, StoreState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Keeps `frame` as the newest (cheap: the run hands over its shared frame).
    pub fn set_newest(&self, evaluation: usize, frame: Arc<Frame>) {
        self.lock().newest = Some((evaluation, frame));
    }

    /// Where the run saves its frames, when it does.
    pub fn set_folder(&self, folder: PathBuf) {
        self.lock().folder = Some(folder);
    }

    pub fn has_folder(&self) -> bool {
        self.lock().folder.is_some()
    }

    /// The frame of `evaluation`, encoded and searched; `Ok(None)` when it is neither the
    /// newest nor saved. Blocking: call it off the async threads.
    pub fn show(&self, evaluation: usize) -> anyhow::Result<Option<ShownFrame>> {
        let (newest, folder) = {
            let state = self.lock();
            if let Some(shown) = state.shown.as_ref().filter(|s| s.evaluation == evaluation) {
                return Ok(Some(shown.clone()));
            }
            let newest = state
                .newest
                .as_ref()
                .filter(|(n, _)| *n == evaluation)
                .map(|(_, frame)| frame.clone());
            (newest, state.folder.clone())
        };
        let (frame, png) = match (newest, folder) {
            (Some(frame), _) => {
                let png = frame.encode_8bit_png().context("encoding the frame")?;
                (frame, png)
            }
            (None, Some(folder)) => {
                let path = folder.join(format!("{evaluation:04}.png"));
                let Ok(png) = std::fs::read(&path) else {
                    return Ok(None);
                };
                let frame = Frame::decode_png(&png)
                    .with_context(|| format!("{} is not a readable PNG", path.display()))?;
                let shown = frame.encode_8bit_png().context("encoding the frame")?;
                (Arc::new(frame), shown)
            }
            (None, None) => return Ok(None),
        };
        let shown = ShownFrame {
            evaluation,
            png: Arc::new(png),
            beams: Arc::new(Detections::of(&frame)),
        };
        self.lock().shown = Some(shown.clone());
        Ok(Some(shown))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame_with_spot(cx: u32, cy: u32) -> Frame {
        let (width, height) = (96, 64);
        let pixels = (0..width * height)
            .map(|i| {
                let (x, y) = (i % width, i / width);
                let d2 = f64::from((x as i32 - cx as i32).pow(2) + (y as i32 - cy as i32).pow(2));
                (10.0 + 200.0 * (-d2 / 18.0).exp()) as u8
            })
            .collect();
        Frame::new(width, height, pixels).unwrap()
    }

    #[test]
    fn the_newest_frame_is_encoded_with_its_beams_and_others_are_absent() {
        let store = FrameStore::default();
        store.set_newest(4, Arc::new(frame_with_spot(30, 20)));
        let shown = store.show(4).unwrap().expect("the newest frame");
        let decoded = Frame::decode_png(&shown.png).unwrap();
        assert_eq!((decoded.width(), decoded.height()), (96, 64));
        let beam = &shown.beams.beams[0];
        assert!(
            (beam.x - 30.0).abs() < 1.5 && (beam.y - 20.0).abs() < 1.5,
            "{beam:?}"
        );
        assert!(store.show(3).unwrap().is_none());
    }

    #[test]
    fn saved_frames_come_from_the_folder() {
        let dir = tempfile::tempdir().unwrap();
        let png = frame_with_spot(60, 40).encode_png().unwrap();
        std::fs::write(dir.path().join("0002.png"), &png).unwrap();
        let store = FrameStore::from_folder(dir.path().to_owned());
        let shown = store.show(2).unwrap().expect("a saved frame");
        assert_eq!(*shown.png, png);
        assert!(store.show(7).unwrap().is_none());
        std::fs::write(dir.path().join("0005.png"), b"not a png").unwrap();
        let error = store.show(5).unwrap_err().to_string();
        assert!(error.contains("0005.png is not a readable PNG"), "{error}");
    }
}
