//! Light that stays put at a camera place, learned from two frames between which the beam moved
//! clear of itself and taken off later frames, on raw levels (no background fit leaves a slope).

use optalign_optics::Frame;

use super::cells::{CellSums, f64_sum};
use super::noise::NoiseMap;
use super::picture::{Picture, median};
use super::tuning::BACKDROP_CELL;

/// The levels a place shows without the beam, gray levels.
#[derive(Clone, Debug)]
pub struct Backdrop {
    width: usize,
    height: usize,
    levels: Vec<f32>,
    /// The read noise of the frames it came from, gray levels.
    noise: f64,
}

impl Backdrop {
    /// The stationary light of two frames between which the beam moved clear of itself: the
    /// darker frame, cell by cell. `noise`: the larger read noise; `None` when the sizes differ.
    pub fn from_pair(a: &Frame, b: &Frame, noise: f64) -> Option<Self> {
        if a.width() != b.width() || a.height() != b.height() || a.full_scale() != b.full_scale() {
            return None;
        }
        let scale = a.levels_per_count();
        let (width, height) = (a.width() as usize, a.height() as usize);
        let sums_a = CellSums::new(a.pixels(), width, height, BACKDROP_CELL, f64_sum);
        let sums_b = CellSums::new(b.pixels(), width, height, BACKDROP_CELL, f64_sum);
        let columns = sums_a.columns;
        let levels = a
            .pixels()
            .iter()
            .zip(b.pixels())
            .enumerate()
            .map(|(i, (&pa, &pb))| {
                let cell = (i / width / BACKDROP_CELL) * columns + (i % width) / BACKDROP_CELL;
                let a_darker = sums_a.sums[cell] <= sums_b.sums[cell];
                f32::from(if a_darker { pa } else { pb }) * scale
            })
            .collect();
        Some(Self {
            width,
            height,
            levels,
            noise,
        })
    }

    /// The stationary light above `picture`'s background, gray levels, row-major.
    pub fn light_above(&self, picture: &Picture) -> Vec<f32> {
        let background = picture.background() as f32;
        self.levels.iter().map(|v| v - background).collect()
    }

    /// `frame` (ready as `picture`) less this light and its typical cell's offset, if sizes match.
    pub fn removed_from(&self, frame: &Frame, picture: &Picture) -> Option<Picture> {
        if frame.width() as usize != self.width || frame.height() as usize != self.height {
            return None;
        }
        let scale = frame.levels_per_count();
        let mut light: Vec<f32> = frame
            .pixels()
            .iter()
            .zip(&self.levels)
            .map(|(&p, b)| f32::from(p) * scale - b)
            .collect();
        let stationary = NoiseMap::uniform(self.width, self.height, self.noise);
        let noise_map = picture.noise_map().of_difference(&stationary, 1.0);
        let cells = CellSums::new(&light, self.width, self.height, BACKDROP_CELL, f64_sum);
        if let Some(offset) = median(cells.means().collect()) {
            light.iter_mut().for_each(|v| *v -= offset as f32);
        }
        Some(picture.with_light(light, picture.noise().hypot(self.noise), noise_map))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::find_beams;
    use crate::synthetic::Scene;

    /// A beam of radius 100 px at `beam` beside a stationary stray spot, its tails touching.
    fn frame(beam: [f64; 2], seed: u64) -> Frame {
        let scene = Scene::new(640, 480)
            .background(6.0, [0.0, 0.0])
            .gaussian([90.0, 346.0], 80.0, 176.0)
            .gaussian(beam, 100.0, 220.0)
            .noise(2.5, seed);
        scene.frame()
    }

    #[test]
    fn a_stray_spot_touching_the_beam_is_taken_off() {
        let later = frame([200.0, 230.0], 3);
        let merged = find_beams(&Picture::new(&later));
        let off = |b: &crate::Beam| (b.centre[0] - 200.0).hypot(b.centre[1] - 230.0);
        assert!(
            merged.iter().all(|b| off(b) > 2.0),
            "the stray should pull the beam without a backdrop: {merged:?}"
        );
        let backdrop =
            Backdrop::from_pair(&frame([190.0, 200.0], 1), &frame([520.0, 150.0], 2), 2.5).unwrap();
        let beams = find_beams(
            &backdrop
                .removed_from(&later, &Picture::new(&later))
                .unwrap(),
        );
        assert_eq!(beams.len(), 1, "{beams:?}");
        assert!(off(&beams[0]) < 1.0, "{:?}", beams[0].centre);
    }
}
