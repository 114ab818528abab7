//! The Michelson interferometer scene: two returning Gaussian beams steered by two two-axis
//! mirrors, coherently superposed with a fixed relative phase gradient (straight fringes where
//! they overlap), cut at the image border, saturated, on a noisy background.

use std::f64::consts::TAU;

use crate::frame::Frame;
use crate::math::spot_span;
use crate::readout::{Readout, scene_key};
use crate::scenario::{MichelsonParams, ScenarioError};

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
}

impl Michelson {
    /// Number of motor axes: mirror 1 (horizontal, vertical), mirror 2 (horizontal, vertical).
    pub const AXES: usize = 4;

    /// A scene whose beams are centred when the shafts read `-offsets`.
    pub fn new(params: MichelsonParams, offsets: [i32; 4]) -> Result<Self, ScenarioError> {
        params.validate()?;
        let key = scene_key(params.noise.seed, &offsets);
        Ok(Self {
            params,
            offsets,
            key,
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

    /// Beam centres in px for the given shaft positions.
    fn centres(&self, shaft: &[i32]) -> [[f64; 2]; 2] {
        assert_eq!(
            shaft.len(),
            Self::AXES,
            "Michelson takes {} axes",
            Self::AXES
        );
        let c = self.image_centre();
        std::array::from_fn(|k| {
            let u = [
                f64::from(shaft[2 * k]) + f64::from(self.offsets[2 * k]),
                f64::from(shaft[2 * k + 1]) + f64::from(self.offsets[2 * k + 1]),
            ];
            let s = self.params.sensitivity(k);
            [
                c[0] + s[0][0] * u[0] + s[0][1] * u[1],
                c[1] + s[1][0] * u[0] + s[1][1] * u[1],
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

    /// Renders the camera frame for the given shaft positions; `frame_index` selects the noise.
    ///
    /// The image is `|E1 + E2 exp(i phi)|^2` with Gaussian fields and a linear phase `phi`.
    /// Both are separable, so per column and per row factors are computed once and each pixel
    /// in the region the beams reach costs four multiply-adds.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn render(&self, shaft: &[i32], frame_index: u64) -> Frame {
        let p = &self.params;
        let (w, h) = (p.width_px as usize, p.height_px as usize);
        let centres = self.centres(shaft);
        let rc = self.image_centre();
        let radius = p.beam_radius_px;
        let peak = p.beam_peak_level;
        let wavenumber = TAU / p.fringe_period_px;
        let angle = p.fringe_angle_deg.to_radians();
        let (kx, ky) = (wavenumber * angle.cos(), wavenumber * angle.sin());

        let spans_x = [0, 1].map(|k| spot_span(centres[k][0], radius[k], w));
        let spans_y = [0, 1].map(|k| spot_span(centres[k][1], radius[k], h));
        let cols = union(&spans_x[0], &spans_x[1]);

        // Column factors: field amplitude exp(-dx^2 / r^2) of each beam, zero outside its span.
        let field = |k: usize, i: usize, spans: &[std::ops::Range<usize>; 2], axis: usize| {
            if spans[k].contains(&i) {
                let d = (i as f64 + 0.5 - centres[k][axis]) / radius[k];
                (-d * d).exp()
            } else {
                0.0
            }
        };
        let cross = 2.0 * (peak[0] * peak[1]).sqrt();
        let n = cols.len();
        let (mut pc, mut qc, mut cc, mut sc) =
            (vec![0f32; n], vec![0f32; n], vec![0f32; n], vec![0f32; n]);
        for (j, i) in cols.clone().enumerate() {
            let f1 = field(0, i, &spans_x, 0);
            let f2 = field(1, i, &spans_x, 0);
            let alpha = kx * (i as f64 + 0.5 - rc[0]);
            pc[j] = (peak[0] * f1 * f1) as f32;
            qc[j] = (peak[1] * f2 * f2) as f32;
            cc[j] = (cross * f1 * f2 * alpha.cos()) as f32;
            sc[j] = (cross * f1 * f2 * alpha.sin()) as f32;
        }

        let readout = Readout::new(&p.noise, self.key, frame_index);
        let mut pixels = vec![0u8; w * h];
        let mut signal = vec![0f32; w];
        for (y, out) in pixels.chunks_exact_mut(w).enumerate() {
            let g1 = field(0, y, &spans_y, 1);
            let g2 = field(1, y, &spans_y, 1);
            if n == 0 || (g1 == 0.0 && g2 == 0.0) {
                readout.finish_row(y as u32, None, out);
                continue;
            }
            let beta = ky * (y as f64 + 0.5 - rc[1]) + p.fringe_phase_rad;
            let a = (g1 * g1) as f32;
            let b = (g2 * g2) as f32;
            let c = (g1 * g2 * beta.cos()) as f32;
            let d = (-g1 * g2 * beta.sin()) as f32;
            let row = &mut signal[cols.clone()];
            for (j, v) in row.iter_mut().enumerate() {
                *v = a * pc[j] + b * qc[j] + c * cc[j] + d * sc[j];
            }
            readout.finish_row(y as u32, Some(&signal), out);
        }
        Frame::new(p.width_px, p.height_px, pixels).expect("buffer sized to the frame")
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
}
