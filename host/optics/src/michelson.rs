//! The Michelson interferometer scene: two returning beams steered by two two-axis mirrors,
//! coherently superposed with a relative phase gradient (straight fringes where they
//! overlap), cut at the image border, saturated, on a noisy background, with whatever
//! realism layers the scenario turns on (beam shapes, flicker, jitter, fringe drift, camera
//! effects).

use std::f64::consts::TAU;

use crate::frame::Frame;
use crate::profile::BeamShape;
use crate::readout::{Readout, mix64, scene_key};
use crate::scenario::{MichelsonParams, ScenarioError};
use crate::sensor::{FrameDraw, Sensor};

/// Hidden truth of one Michelson state, for scoring only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MichelsonTruth {
    /// Centres of beam 1 and beam 2, px (x right, y down); may lie off the image.
    pub beam_centres_px: [[f64; 2]; 2],
    /// The target: the image centre, px.
    pub image_centre_px: [f64; 2],
    /// e = |r1 - rc| + |r2 - rc|, px.
    pub error_px: f64,
}

/// A Michelson scene with fixed hidden offsets.
#[derive(Debug, Clone)]
pub struct Michelson {
    params: MichelsonParams,
    offsets: [i32; 4],
    key: u64,
    shapes: [BeamShape; 2],
    sensor: Sensor,
}

/// Periods of the three incommensurate waves that make up the fringe drift, frames.
const DRIFT_PERIODS: [f64; 3] = [7.3, 17.9, 41.1];

impl Michelson {
    /// Number of motor axes: mirror 1 (horizontal, vertical), mirror 2 (horizontal, vertical).
    pub const AXES: usize = 4;

    /// A scene whose beams are centred when the shafts read `-offsets`.
    pub fn new(params: MichelsonParams, offsets: [i32; 4]) -> Result<Self, ScenarioError> {
        params.validate()?;
        let key = scene_key(params.noise.seed, &offsets);
        let realism = &params.realism;
        let orientation = realism.orientation();
        let shape = |k: usize| {
            let r = params.beam_radius_px[k];
            BeamShape::new(
                realism.profile(k),
                &realism.texture,
                [r, r],
                orientation,
                mix64(params.noise.seed ^ k as u64),
            )
            .map_err(|reason| ScenarioError::Invalid {
                field: "michelson.realism.beam_profile".into(),
                reason,
            })
        };
        let shapes = [shape(0)?, shape(1)?];
        let sensor = Sensor::new(
            realism,
            params.width_px as usize,
            params.height_px as usize,
            key,
        )
        .map_err(|reason| ScenarioError::Invalid {
            field: "michelson.realism.background_photo".into(),
            reason,
        })?;
        Ok(Self {
            params,
            offsets,
            key,
            shapes,
            sensor,
        })
    }

    /// The parameters this scene was built with.
    pub fn params(&self) -> &MichelsonParams {
        &self.params
    }

    fn image_centre(&self) -> [f64; 2] {
        [
            f64::from(self.params.width_px) / 2.0,
            f64::from(self.params.height_px) / 2.0,
        ]
    }

    /// Beam centres in px for the given shaft positions (without jitter).
    fn centres(&self, shaft: &[i32]) -> [[f64; 2]; 2] {
        assert_eq!(
            shaft.len(),
            Self::AXES,
            "Michelson takes {} axes",
            Self::AXES
        );
        let c = self.image_centre();
        let o = self.params.realism.orientation();
        std::array::from_fn(|k| {
            let u = [
                f64::from(shaft[2 * k]) + f64::from(self.offsets[2 * k]),
                f64::from(shaft[2 * k + 1]) + f64::from(self.offsets[2 * k + 1]),
            ];
            let s = self.params.sensitivity(k);
            let d = [
                s[0][0] * u[0] + s[0][1] * u[1],
                s[1][0] * u[0] + s[1][1] * u[1],
            ];
            [
                c[0] + o[0][0] * d[0] + o[0][1] * d[1],
                c[1] + o[1][0] * d[0] + o[1][1] * d[1],
            ]
        })
    }

    /// The hidden truth for the given shaft positions.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn truth(&self, shaft: &[i32]) -> MichelsonTruth {
        let centres = self.centres(shaft);
        let rc = self.image_centre();
        let dist = |r: [f64; 2]| (r[0] - rc[0]).hypot(r[1] - rc[1]);
        MichelsonTruth {
            beam_centres_px: centres,
            image_centre_px: rc,
            error_px: dist(centres[0]) + dist(centres[1]),
        }
    }

    /// The relative phase at the image centre in frame `frame_index`: the configured phase
    /// plus the drift, a sum of three slow incommensurate waves of RMS `fringe_drift_rad`.
    fn phase(&self, frame_index: u64) -> f64 {
        let p = &self.params;
        if p.fringe_drift_rad == 0.0 {
            return p.fringe_phase_rad;
        }
        let amplitude = p.fringe_drift_rad * (2.0f64 / 3.0).sqrt();
        let t = frame_index as f64;
        p.fringe_phase_rad
            + DRIFT_PERIODS
                .iter()
                .enumerate()
                .map(|(i, period)| {
                    let start =
                        TAU * (mix64(self.key ^ (i as u64 + 1)) >> 11) as f64 / (1u64 << 53) as f64;
                    amplitude * (TAU * t / period + start).sin()
                })
                .sum::<f64>()
    }

    /// Renders the camera frame for the given shaft positions; `frame_index` selects the
    /// noise and the per-frame draws of the realism layers.
    ///
    /// The image is `|E1 + E2 exp(i phi)|^2` with the beams' fields and a linear phase
    /// `phi`, whose cosine splits into per-column and per-row factors computed once.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn render(&self, shaft: &[i32], frame_index: u64) -> Frame {
        let p = &self.params;
        let (w, h) = (p.width_px as usize, p.height_px as usize);
        let draw = FrameDraw::new(&p.realism, self.key, frame_index);
        let truth = self.centres(shaft);
        let placed = [0, 1].map(|k| {
            let centre = [
                truth[k][0] + draw.jitter[k][0],
                truth[k][1] + draw.jitter[k][1],
            ];
            self.shapes[k].place(centre, [w, h])
        });
        let peak = p.beam_peak_level.map(|level| level * draw.gain);
        let cross = (2.0 * (peak[0] * peak[1]).sqrt()) as f32;
        let peak = peak.map(|level| level as f32);
        let rc = self.image_centre();
        let o = p.realism.orientation();
        let wavenumber = TAU / p.fringe_period_px;
        let angle = p.fringe_angle_deg.to_radians();
        let k0 = [wavenumber * angle.cos(), wavenumber * angle.sin()];
        let (kx, ky) = (
            o[0][0] * k0[0] + o[0][1] * k0[1],
            o[1][0] * k0[0] + o[1][1] * k0[1],
        );
        let phase = self.phase(frame_index);

        let cols = union(&placed[0].cols(), &placed[1].cols());
        let (cos_x, sin_x): (Vec<f32>, Vec<f32>) = cols
            .clone()
            .map(|i| {
                let alpha = kx * (i as f64 + 0.5 - rc[0]);
                (alpha.cos() as f32, alpha.sin() as f32)
            })
            .unzip();
        let mut fields = [vec![0f32; w], vec![0f32; w]];
        let readout = Readout::new(&p.noise, self.key, frame_index);
        let pixels = self.sensor.expose(&readout, |y, row| {
            let [e1, e2] = &mut fields;
            e1[cols.clone()].fill(0.0);
            e2[cols.clone()].fill(0.0);
            let lit1 = placed[0].amplitude_row(y, 1.0, e1);
            let lit2 = placed[1].amplitude_row(y, 1.0, e2);
            if !lit1 && !lit2 {
                return false;
            }
            let beta = ky * (y as f64 + 0.5 - rc[1]) + phase;
            let (cb, sb) = (beta.cos() as f32, beta.sin() as f32);
            for (j, x) in cols.clone().enumerate() {
                let (a, b) = (e1[x], e2[x]);
                let fringe = cb * cos_x[j] - sb * sin_x[j];
                row[x] = peak[0] * a * a + peak[1] * b * b + cross * a * b * fringe;
            }
            true
        });
        Frame::deep(p.width_px, p.height_px, pixels, readout.full_scale())
            .expect("buffer sized to the frame")
    }
}

/// The smallest range covering both (either may be empty).
fn union(a: &std::ops::Range<usize>, b: &std::ops::Range<usize>) -> std::ops::Range<usize> {
    match (a.is_empty(), b.is_empty()) {
        (true, _) => b.clone(),
        (_, true) => a.clone(),
        _ => a.start.min(b.start)..a.end.max(b.end),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn union_of_spans() {
        assert_eq!(union(&(3..3), &(5..9)), 5..9);
        assert_eq!(union(&(5..9), &(0..0)), 5..9);
        assert_eq!(union(&(5..9), &(20..30)), 5..30);
    }

    /// The centroid of the light well above the noise floor, px.
    fn centroid(frame: &Frame) -> [f64; 2] {
        let threshold = 30.0;
        let (mut sum, mut sx, mut sy) = (0.0, 0.0, 0.0);
        for y in 0..frame.height() {
            for x in 0..frame.width() {
                let light = (f64::from(frame.pixel(x, y)) - threshold).max(0.0);
                sum += light;
                sx += light * (f64::from(x) + 0.5);
                sy += light * (f64::from(y) + 0.5);
            }
        }
        [sx / sum, sy / sum]
    }

    #[test]
    fn a_binned_camera_sees_the_light_where_the_full_one_does_scaled() {
        let params = MichelsonParams::default();
        let offsets = [900, -700, -1200, 500];
        let full = Michelson::new(params.clone(), offsets).unwrap();
        let binned = Michelson::new(params.binned(160, 90).unwrap(), offsets).unwrap();
        let shafts = [0, 0, 0, 0];
        let small = binned.render(&shafts, 0);
        assert_eq!((small.width(), small.height()), (160, 90));
        let [fx, fy] = centroid(&full.render(&shafts, 0));
        let [bx, by] = centroid(&small);
        assert!(
            (fx / 12.0 - bx).abs() < 1.0 && (fy / 12.0 - by).abs() < 1.0,
            "full {fx:.1},{fy:.1} binned {bx:.1},{by:.1}"
        );
        let truth = binned.truth(&shafts);
        assert!((truth.error_px * 12.0 - full.truth(&shafts).error_px).abs() < 1e-6);
    }

    #[test]
    fn binning_is_refused_where_it_would_not_be_faithful() {
        let params = MichelsonParams::default();
        assert!(params.binned(160, 120).is_none(), "another aspect");
        assert!(params.binned(1920, 1080).is_none(), "not smaller");
        assert!(params.binned(32, 18).is_none(), "fringes under two pixels");
        let mut textured = params.clone();
        textured.realism.pointing_jitter_px = 2.0;
        assert!(textured.binned(160, 90).is_none(), "realism layers on");
    }
}
