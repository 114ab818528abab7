//! What the camera adds to a scene's light, shared by the three scenes: the per-frame
//! random draws of the realism layers (laser power flicker, each beam's pointing jitter),
//! stationary light that no motor moves (ambient, a sloping background, stray spots, a
//! photograph of a real camera's background), a
//! read-out smear column under bright light, hot pixels, and then the read-out itself
//! (dark level, noise, saturation). A scene hands over its light row by row.

use std::f64::consts::TAU;
use std::ops::Range;

use crate::math::{gaussian_profile, spot_span};
use crate::photo::Photo;
use crate::readout::{Readout, mix64};
use crate::scenario::{RealismParams, StraySpot};

/// Salts that keep the per-frame draws independent of each other and of the noise.
const FLICKER_SALT: u64 = 0x666c_6963_6b65_7221;
const JITTER_SALT: u64 = 0x6a69_7474_6572_2121;
const HOT_PIXEL_SALT: u64 = 0x686f_7470_6978_656c;

/// Uniform in [0, 1) from a hash.
fn unit(hash: u64) -> f64 {
    (hash >> 11) as f64 / (1u64 << 53) as f64
}

/// A standard normal draw fixed by `key` (Box-Muller on two hashes).
pub(crate) fn normal(key: u64) -> f64 {
    let u1 = 1.0 - unit(mix64(key));
    let u2 = unit(mix64(key ^ 0x5bd1_e995_5bd1_e995));
    (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
}

/// The random part of one frame: the laser power factor and each beam's displacement.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) struct FrameDraw {
    /// Factor on all laser light (1 without flicker).
    pub gain: f64,
    /// Displacement of beam k, px.
    pub jitter: [[f64; 2]; 2],
}

impl FrameDraw {
    /// The draw of frame `frame_index` of a scene with noise key `key`.
    pub(crate) fn new(realism: &RealismParams, key: u64, frame_index: u64) -> Self {
        let frame = mix64(key ^ mix64(frame_index.wrapping_add(FLICKER_SALT)));
        let gain = (1.0 + realism.power_flicker * normal(frame ^ FLICKER_SALT)).max(0.0);
        let sigma = realism.pointing_jitter_px;
        let jitter = std::array::from_fn(|k| {
            std::array::from_fn(|axis| {
                let salt = JITTER_SALT.wrapping_add((2 * k + axis) as u64);
                sigma * normal(frame ^ mix64(salt))
            })
        });
        Self { gain, jitter }
    }
}

/// A stray spot placed on the image.
#[derive(Debug, Clone)]
struct PlacedSpot {
    cols: Range<usize>,
    rows: Range<usize>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    peak: f32,
}

/// The camera's own contributions to every frame of one scene.
#[derive(Debug, Clone)]
pub(crate) struct Sensor {
    width: usize,
    height: usize,
    /// Ambient light plus the horizontal part of the slope, per column.
    column_light: Vec<f32>,
    /// Vertical slope per row, gray levels.
    row_slope: Vec<f32>,
    stray: Vec<PlacedSpot>,
    /// A photographed background, gray levels, row-major.
    photo: Option<Vec<f32>>,
    smear: f32,
    /// Hot pixels (index) and their level above the dark level.
    hot: Vec<usize>,
    hot_level: f64,
    /// Whether the stationary light is zero everywhere.
    dark: bool,
}

impl Sensor {
    /// The sensor of a `width` x `height` camera with `realism`; `key` places hot pixels.
    /// An error says why the background photograph cannot be used.
    pub(crate) fn new(
        realism: &RealismParams,
        width: usize,
        height: usize,
        key: u64,
    ) -> Result<Self, String> {
        let photo = match &realism.background_photo {
            Some(spec) => {
                let gain = spec.gain as f32;
                let mut levels = Photo::load(&spec.path)?
                    .erased(&spec.erase)?
                    .resampled(width, height);
                levels.iter_mut().for_each(|v| *v *= gain);
                Some(levels)
            }
            None => None,
        };
        let centre = [width as f64 / 2.0, height as f64 / 2.0];
        let [gx, gy] = realism.gradient_levels;
        let column_light = (0..width)
            .map(|x| (realism.ambient_level + gx * (x as f64 + 0.5 - centre[0]) / centre[0]) as f32)
            .collect();
        let row_slope = (0..height)
            .map(|y| (gy * (y as f64 + 0.5 - centre[1]) / centre[1]) as f32)
            .collect();
        let stray = realism
            .stray_spots
            .iter()
            .map(|spot| place_spot(spot, centre, [width, height]))
            .filter(|s| !s.cols.is_empty() && !s.rows.is_empty())
            .collect::<Vec<_>>();
        let pixels = width * height;
        let wanted = (realism.hot_pixels as usize).min(pixels);
        let mut hot = std::collections::BTreeSet::new();
        let mut draw = 0u64;
        while hot.len() < wanted {
            hot.insert((mix64(key ^ HOT_PIXEL_SALT ^ mix64(draw)) % pixels as u64) as usize);
            draw += 1;
        }
        let hot = hot.into_iter().collect();
        let dark = realism.ambient_level == 0.0
            && gx == 0.0
            && gy == 0.0
            && stray.is_empty()
            && photo.is_none();
        Ok(Self {
            width,
            height,
            column_light,
            row_slope,
            stray,
            photo,
            smear: realism.smear as f32,
            hot,
            hot_level: realism.hot_pixel_level,
            dark,
        })
    }

    /// Reads out a frame: `light(y, row)` adds the scene's light of row `y` into the zeroed
    /// `row` and returns whether it added any.
    pub(crate) fn expose(
        &self,
        readout: &Readout,
        mut light: impl FnMut(usize, &mut [f32]) -> bool,
    ) -> Vec<u16> {
        let (w, h) = (self.width, self.height);
        let mut pixels = vec![0u16; w * h];
        if self.smear > 0.0 {
            self.expose_with_smear(readout, &mut light, &mut pixels);
        } else {
            let mut row = vec![0f32; w];
            for (y, out) in pixels.chunks_exact_mut(w).enumerate() {
                let lit = light(y, &mut row);
                if self.dark {
                    readout.finish_row(y as u32, lit.then_some(&row[..]), out);
                    if lit {
                        row.fill(0.0);
                    }
                } else {
                    self.add_stationary(y, &mut row);
                    readout.finish_row(y as u32, Some(&row), out);
                    row.fill(0.0);
                }
            }
        }
        for &i in &self.hot {
            pixels[i] = pixels[i].max(readout.level(self.hot_level));
        }
        pixels
    }

    /// The whole frame's light first, then each column's smear (a share of its mean light).
    fn expose_with_smear(
        &self,
        readout: &Readout,
        light: &mut impl FnMut(usize, &mut [f32]) -> bool,
        pixels: &mut [u16],
    ) {
        let (w, h) = (self.width, self.height);
        let mut frame = vec![0f32; w * h];
        for (y, row) in frame.chunks_exact_mut(w).enumerate() {
            light(y, row);
            self.add_stationary(y, row);
        }
        let mut smear = vec![0f32; w];
        for row in frame.chunks_exact(w) {
            for (s, v) in smear.iter_mut().zip(row) {
                *s += v.max(0.0);
            }
        }
        let share = self.smear / h as f32;
        smear.iter_mut().for_each(|s| *s *= share);
        for (y, (row, out)) in frame
            .chunks_exact_mut(w)
            .zip(pixels.chunks_exact_mut(w))
            .enumerate()
        {
            for (v, s) in row.iter_mut().zip(&smear) {
                *v += s;
            }
            readout.finish_row(y as u32, Some(row), out);
        }
    }

    /// Adds ambient light, the slope and stray spots to row `y`.
    fn add_stationary(&self, y: usize, row: &mut [f32]) {
        if self.dark {
            return;
        }
        let slope = self.row_slope[y];
        for (v, c) in row.iter_mut().zip(&self.column_light) {
            *v += c + slope;
        }
        if let Some(photo) = &self.photo {
            let w = self.width;
            for (v, p) in row.iter_mut().zip(&photo[y * w..(y + 1) * w]) {
                *v += p;
            }
        }
        for spot in &self.stray {
            if spot.rows.contains(&y) {
                let a = spot.peak * spot.gy[y - spot.rows.start];
                for (v, g) in row[spot.cols.clone()].iter_mut().zip(&spot.gx) {
                    *v += a * g;
                }
            }
        }
    }
}

fn place_spot(spot: &StraySpot, centre: [f64; 2], size: [usize; 2]) -> PlacedSpot {
    let c = [
        centre[0] + spot.centre_offset_px[0],
        centre[1] + spot.centre_offset_px[1],
    ];
    let cols = spot_span(c[0], spot.radius_px, size[0]);
    let rows = spot_span(c[1], spot.radius_px, size[1]);
    PlacedSpot {
        gx: gaussian_profile(c[0], spot.radius_px, cols.clone()),
        gy: gaussian_profile(c[1], spot.radius_px, rows.clone()),
        cols,
        rows,
        peak: spot.peak_level as f32,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::NoiseParams;

    fn quiet() -> NoiseParams {
        NoiseParams {
            std: 0.0,
            ..NoiseParams::default()
        }
    }

    #[test]
    fn draws_are_deterministic_and_have_the_configured_spread() {
        let realism = RealismParams {
            power_flicker: 0.1,
            pointing_jitter_px: 3.0,
            ..RealismParams::default()
        };
        let draws: Vec<FrameDraw> = (0..4000).map(|i| FrameDraw::new(&realism, 7, i)).collect();
        assert_eq!(draws[5], FrameDraw::new(&realism, 7, 5));
        let n = draws.len() as f64;
        let gain_std = (draws.iter().map(|d| (d.gain - 1.0).powi(2)).sum::<f64>() / n).sqrt();
        let jitter_std = (draws.iter().map(|d| d.jitter[1][0].powi(2)).sum::<f64>() / n).sqrt();
        assert!((gain_std - 0.1).abs() < 0.01, "{gain_std}");
        assert!((jitter_std - 3.0).abs() < 0.2, "{jitter_std}");
        let plain = FrameDraw::new(&RealismParams::default(), 7, 3);
        assert_eq!(plain.gain, 1.0);
        assert_eq!(plain.jitter, [[0.0; 2]; 2]);
    }

    #[test]
    fn ambient_slope_stray_spot_and_hot_pixels_show() {
        let realism = RealismParams {
            ambient_level: 20.0,
            gradient_levels: [10.0, 0.0],
            hot_pixels: 5,
            hot_pixel_level: 240.0,
            stray_spots: vec![StraySpot {
                centre_offset_px: [30.0, 0.0],
                radius_px: 8.0,
                peak_level: 100.0,
            }],
            ..RealismParams::default()
        };
        let (w, h) = (200usize, 100usize);
        let sensor = Sensor::new(&realism, w, h, 3).unwrap();
        let pixels = sensor.expose(&Readout::new(&quiet(), 1, 0), |_, _| false);
        let at = |x: usize, y: usize| pixels[y * w + x];
        // Dark level 6 + ambient 20, +-10 across the frame.
        assert_eq!(at(100, 10), 26);
        assert!((at(0, 10) as i32 - 16).abs() <= 1 && (at(199, 10) as i32 - 36).abs() <= 1);
        assert!(at(130, 50) >= 126, "{}", at(130, 50));
        assert_eq!(pixels.iter().filter(|&&p| p >= 246).count(), 5);
    }

    #[test]
    fn smear_draws_a_column_under_bright_light() {
        let realism = RealismParams {
            smear: 0.5,
            ..RealismParams::default()
        };
        let (w, h) = (100usize, 100usize);
        let sensor = Sensor::new(&realism, w, h, 3).unwrap();
        // A bright 10-row bar in column 40 (light 1000 per pixel).
        let pixels = sensor.expose(&Readout::new(&quiet(), 1, 0), |y, row| {
            if (45..55).contains(&y) {
                row[40] = 1000.0;
                true
            } else {
                false
            }
        });
        // Column mean 100, half of it smeared into every pixel of the column.
        assert_eq!(pixels[5 * w + 40], 56);
        assert_eq!(pixels[5 * w + 41], 6);
    }
}
