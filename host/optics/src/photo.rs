//! Photographs in simulated scenes: a camera frame read once per path and process, in gray
//! levels of an 8-bit frame at full precision (16-bit photographs keep their fractions), a
//! part of it cut out (the beam a profile takes), parts of it filled in from their rims (the
//! photographed beam taken out of a photograph used as the stationary background), and the
//! whole resampled to another frame size.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use crate::frame::Frame;

/// A photograph's gray levels, row-major.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Photo {
    pub width: usize,
    pub height: usize,
    pub levels: Vec<f32>,
}

impl Photo {
    /// Reads `path` (PNG, JPEG or TIFF; colour taken as luminance), once per process.
    pub(crate) fn load(path: &Path) -> Result<Arc<Photo>, String> {
        static CACHE: OnceLock<Mutex<HashMap<PathBuf, Arc<Photo>>>> = OnceLock::new();
        let cache = CACHE.get_or_init(Default::default);
        if let Some(photo) = cache.lock().unwrap_or_else(|e| e.into_inner()).get(path) {
            return Ok(photo.clone());
        }
        let bytes = std::fs::read(path)
            .map_err(|e| format!("cannot read photo {}: {e}", path.display()))?;
        let frame = Frame::decode(&bytes, None)
            .map_err(|e| format!("photo {} is not a usable image: {e}", path.display()))?;
        let scale = frame.levels_per_count();
        let photo = Arc::new(Photo {
            width: frame.width() as usize,
            height: frame.height() as usize,
            levels: frame
                .pixels()
                .iter()
                .map(|&p| f32::from(p) * scale)
                .collect(),
        });
        cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(path.to_owned(), photo.clone());
        Ok(photo)
    }

    /// The part `[x, y, width, height]` of the photo, px; an error names a box that does not
    /// lie inside it.
    pub(crate) fn cropped(&self, area: [u32; 4]) -> Result<Photo, String> {
        let [x, y, w, h] = area.map(|v| v as usize);
        self.check_inside(area)?;
        let levels = (y..y + h)
            .flat_map(|row| self.levels[row * self.width + x..row * self.width + x + w].to_vec())
            .collect();
        Ok(Photo {
            width: w,
            height: h,
            levels,
        })
    }

    /// The photo with each box `[x, y, width, height]` filled in from its rim: every pixel
    /// inside takes the blend of the rim's four sides that a bilinear (Coons) patch gives,
    /// so a photographed beam leaves the background's slope and no spot behind.
    pub(crate) fn erased(&self, boxes: &[[u32; 4]]) -> Result<Photo, String> {
        let mut photo = self.clone();
        for &area in boxes {
            photo.check_inside(area)?;
            let [x0, y0, w, h] = area.map(|v| v as usize);
            // The rim: the rows and columns just outside the box (clamped to the photo).
            let (left, right) = (x0.saturating_sub(1), (x0 + w).min(self.width - 1));
            let (top, bottom) = (y0.saturating_sub(1), (y0 + h).min(self.height - 1));
            let at = |x: usize, y: usize| photo.levels[y * self.width + x];
            let mut filled = Vec::with_capacity(w * h);
            let (span_x, span_y) = ((right - left).max(1) as f32, (bottom - top).max(1) as f32);
            for y in y0..y0 + h {
                let v = (y - top) as f32 / span_y;
                for x in x0..x0 + w {
                    let u = (x - left) as f32 / span_x;
                    let sides = (1.0 - u) * at(left, y)
                        + u * at(right, y)
                        + (1.0 - v) * at(x, top)
                        + v * at(x, bottom);
                    let corners = (1.0 - u) * (1.0 - v) * at(left, top)
                        + u * (1.0 - v) * at(right, top)
                        + (1.0 - u) * v * at(left, bottom)
                        + u * v * at(right, bottom);
                    filled.push(sides - corners);
                }
            }
            for (row, values) in filled.chunks_exact(w).enumerate() {
                let start = (y0 + row) * self.width + x0;
                photo.levels[start..start + w].copy_from_slice(values);
            }
        }
        Ok(photo)
    }

    /// The photo stretched over a `width` x `height` frame (bilinear).
    pub(crate) fn resampled(&self, width: usize, height: usize) -> Vec<f32> {
        let (sx, sy) = (
            self.width as f64 / width as f64,
            self.height as f64 / height as f64,
        );
        let mut out = Vec::with_capacity(width * height);
        for y in 0..height {
            let py = ((y as f64 + 0.5) * sy - 0.5).clamp(0.0, (self.height - 1) as f64);
            let (j, fy) = (py.floor() as usize, (py - py.floor()) as f32);
            let j1 = (j + 1).min(self.height - 1);
            for x in 0..width {
                let px = ((x as f64 + 0.5) * sx - 0.5).clamp(0.0, (self.width - 1) as f64);
                let (i, fx) = (px.floor() as usize, (px - px.floor()) as f32);
                let i1 = (i + 1).min(self.width - 1);
                let at = |i: usize, j: usize| self.levels[j * self.width + i];
                out.push(
                    (1.0 - fy) * ((1.0 - fx) * at(i, j) + fx * at(i1, j))
                        + fy * ((1.0 - fx) * at(i, j1) + fx * at(i1, j1)),
                );
            }
        }
        out
    }

    fn check_inside(&self, [x, y, w, h]: [u32; 4]) -> Result<(), String> {
        let inside = w > 0
            && h > 0
            && u64::from(x) + u64::from(w) <= self.width as u64
            && u64::from(y) + u64::from(h) <= self.height as u64;
        if inside {
            Ok(())
        } else {
            Err(format!(
                "box [{x}, {y}, {w}, {h}] (x, y, width, height) does not lie inside the \
                 {} x {} px photo",
                self.width, self.height
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp() -> Photo {
        let (width, height) = (20, 10);
        Photo {
            width,
            height,
            levels: (0..width * height)
                .map(|i| (i % width) as f32 + 2.0 * (i / width) as f32)
                .collect(),
        }
    }

    #[test]
    fn crops_erases_and_resamples() {
        let photo = ramp();
        let part = photo.cropped([2, 3, 4, 2]).unwrap();
        assert_eq!(
            part.levels,
            vec![8.0, 9.0, 10.0, 11.0, 10.0, 11.0, 12.0, 13.0]
        );
        assert!(
            photo
                .cropped([18, 0, 4, 2])
                .unwrap_err()
                .contains("does not lie")
        );
        // A spot on the ramp, erased: the ramp comes back exactly (it is bilinear).
        let mut spotted = photo.clone();
        spotted.levels[5 * 20 + 8] += 100.0;
        let clean = spotted.erased(&[[6, 3, 5, 4]]).unwrap();
        for (got, want) in clean.levels.iter().zip(&photo.levels) {
            assert!((got - want).abs() < 1e-4, "{got} vs {want}");
        }
        let half = photo.resampled(10, 5);
        assert_eq!(half.len(), 50);
        assert!((half[0] - (0.5 + 2.0 * 0.5)).abs() < 1e-4, "{}", half[0]);
    }
}
