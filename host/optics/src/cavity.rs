//! The two-mirror cavity scene: a bright, partly saturated primary beam fixed on the image,
//! a dim secondary beam translated linearly by the in-coupler's two motors, stationary
//! artefacts (ring, halo, ghost spots) and noise, summed in intensity without interference,
//! with whatever realism layers the scenario turns on.

use crate::frame::Frame;
use crate::math::{gaussian_profile, spot_span};
use crate::profile::BeamShape;
use crate::readout::{Readout, mix64, scene_key};
use crate::scenario::{CavityParams, ScenarioError};
use crate::sensor::{FrameDraw, Sensor};

/// Hidden truth of one cavity state, for scoring only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CavityTruth {
    /// Centre of the fixed primary beam, px (x right, y down).
    pub primary_centre_px: [f64; 2],
    /// Centre of the secondary beam, px; may lie off the image.
    pub secondary_centre_px: [f64; 2],
    /// Distance of the motors from the aligned reference, motor steps:
    /// sqrt((ux - ux*)^2 + (uy - uy*)^2).
    pub error_steps: f64,
    /// `error_steps <= success_error_steps`.
    pub success: bool,
}

/// A cavity scene with fixed hidden offsets.
#[derive(Debug, Clone)]
pub struct Cavity {
    params: CavityParams,
    offsets: [i32; 2],
    key: u64,
    primary_centre: [f64; 2],
    /// Everything that never moves (primary, ring, halo, ghosts), gray levels, row-major.
    stationary: Vec<f32>,
    secondary: BeamShape,
    sensor: Sensor,
}

impl Cavity {
    /// Number of motor axes: 0 = x (motor 3), 1 = y (motor 1).
    pub const AXES: usize = 2;

    /// A scene whose secondary sits on the primary when the shafts read `-offsets`.
    /// Precomputes the stationary part of the image.
    pub fn new(params: CavityParams, offsets: [i32; 2]) -> Result<Self, ScenarioError> {
        params.validate()?;
        let key = scene_key(params.noise.seed, &offsets);
        let centre = [
            f64::from(params.width_px) / 2.0,
            f64::from(params.height_px) / 2.0,
        ];
        let primary_centre = [
            centre[0] + params.primary.centre_offset_px[0],
            centre[1] + params.primary.centre_offset_px[1],
        ];
        let realism = &params.realism;
        let shape = |radius: f64, salt: u64| {
            BeamShape::new(
                &realism.beam_profile,
                &realism.texture,
                [radius, radius],
                realism.orientation(),
                mix64(params.noise.seed ^ salt),
            )
            .map_err(|reason| ScenarioError::Invalid {
                field: "cavity.realism.beam_profile".into(),
                reason,
            })
        };
        let primary = shape(params.primary.radius_px, 0)?;
        let secondary = shape(params.secondary.radius_px, 1)?;
        let stationary = stationary_layer(&params, centre, primary_centre, &primary);
        let sensor = Sensor::new(
            realism,
            params.width_px as usize,
            params.height_px as usize,
            key,
        )
        .map_err(|reason| ScenarioError::Invalid {
            field: "cavity.realism.background_photo".into(),
            reason,
        })?;
        Ok(Self {
            params,
            offsets,
            key,
            primary_centre,
            stationary,
            secondary,
            sensor,
        })
    }

    /// The parameters this scene was built with.
    pub fn params(&self) -> &CavityParams {
        &self.params
    }

    /// Motor positions relative to the aligned reference, steps.
    fn error_vector(&self, shaft: &[i32]) -> [f64; 2] {
        assert_eq!(
            shaft.len(),
            Self::AXES,
            "the cavity takes {} axes",
            Self::AXES
        );
        [0, 1].map(|i| f64::from(shaft[i]) + f64::from(self.offsets[i]))
    }

    fn secondary_centre(&self, shaft: &[i32]) -> [f64; 2] {
        let u = self.error_vector(shaft);
        let s = &self.params.secondary.sensitivity_px_per_step;
        let d = [
            s[0][0] * u[0] + s[0][1] * u[1],
            s[1][0] * u[0] + s[1][1] * u[1],
        ];
        let o = self.params.realism.orientation();
        [
            self.primary_centre[0] + o[0][0] * d[0] + o[0][1] * d[1],
            self.primary_centre[1] + o[1][0] * d[0] + o[1][1] * d[1],
        ]
    }

    /// The hidden truth for the given shaft positions.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn truth(&self, shaft: &[i32]) -> CavityTruth {
        let u = self.error_vector(shaft);
        let error_steps = u[0].hypot(u[1]);
        CavityTruth {
            primary_centre_px: self.primary_centre,
            secondary_centre_px: self.secondary_centre(shaft),
            error_steps,
            success: error_steps <= self.params.success_error_steps,
        }
    }

    /// Renders the camera frame for the given shaft positions; `frame_index` selects the
    /// noise and the per-frame draws of the realism layers (the laser's flicker scales all
    /// its light; jitter moves the primary with its artefacts, by whole pixels, and the
    /// secondary on its own).
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn render(&self, shaft: &[i32], frame_index: u64) -> Frame {
        let p = &self.params;
        let (w, h) = (p.width_px as usize, p.height_px as usize);
        let draw = FrameDraw::new(&p.realism, self.key, frame_index);
        let truth = self.secondary_centre(shaft);
        let centre = [truth[0] + draw.jitter[1][0], truth[1] + draw.jitter[1][1]];
        let secondary = self.secondary.place(centre, [w, h]);
        let peak = (p.secondary.peak_level * draw.gain) as f32;
        let gain = draw.gain as f32;
        let shift = draw.jitter[0].map(|d| d.round() as isize);
        let mut scratch = vec![0f32; w];
        let readout = Readout::new(&p.noise, self.key, frame_index);
        let pixels = self.sensor.expose(&readout, |y, row| {
            let source = y as isize - shift[1];
            if (0..h as isize).contains(&source) {
                let still = &self.stationary[source as usize * w..(source as usize + 1) * w];
                if shift[0] == 0 && gain == 1.0 {
                    row.copy_from_slice(still);
                } else {
                    for (x, v) in row.iter_mut().enumerate() {
                        let from = x as isize - shift[0];
                        if (0..w as isize).contains(&from) {
                            *v = gain * still[from as usize];
                        }
                    }
                }
            }
            secondary.add_intensity_row(y, peak, &mut scratch, row);
            true
        });
        Frame::deep(p.width_px, p.height_px, pixels, readout.full_scale())
            .expect("buffer sized to the frame")
    }
}

/// The image of everything that never moves: primary beam, ring, halo and ghosts.
fn stationary_layer(
    p: &CavityParams,
    centre: [f64; 2],
    primary: [f64; 2],
    shape: &BeamShape,
) -> Vec<f32> {
    let (w, h) = (p.width_px as usize, p.height_px as usize);
    let mut layer = vec![0f32; w * h];
    // Radially symmetric parts around the primary.
    for (y, row) in layer.chunks_exact_mut(w).enumerate() {
        let dy = y as f64 + 0.5 - primary[1];
        for (x, v) in row.iter_mut().enumerate() {
            let dx = x as f64 + 0.5 - primary[0];
            let r2 = dx * dx + dy * dy;
            let r = r2.sqrt();
            let halo = p.halo.level * (-2.0 * r2 / p.halo.radius_px.powi(2)).exp();
            let ring_d = (r - p.ring.radius_px) / p.ring.width_px;
            let ring = p.ring.level * (-ring_d * ring_d).exp();
            *v = (halo + ring) as f32;
        }
    }
    // The primary beam, in the laser's profile.
    let placed = shape.place(primary, [w, h]);
    let mut scratch = vec![0f32; w];
    let peak = p.primary.peak_level as f32;
    for (y, row) in layer.chunks_exact_mut(w).enumerate() {
        placed.add_intensity_row(y, peak, &mut scratch, row);
    }
    // Ghost spots, each added over the region it reaches.
    for ghost in &p.ghosts {
        let gc = [
            centre[0] + ghost.centre_offset_px[0],
            centre[1] + ghost.centre_offset_px[1],
        ];
        let cols = spot_span(gc[0], ghost.radius_px, w);
        let rows = spot_span(gc[1], ghost.radius_px, h);
        let gx = gaussian_profile(gc[0], ghost.radius_px, cols.clone());
        let gy = gaussian_profile(gc[1], ghost.radius_px, rows.clone());
        for (y, fy) in rows.zip(&gy) {
            let row = &mut layer[y * w..(y + 1) * w];
            let a = ghost.peak_level as f32 * fy;
            for (v, fx) in row[cols.clone()].iter_mut().zip(&gx) {
                *v += a * fx;
            }
        }
    }
    layer
}
