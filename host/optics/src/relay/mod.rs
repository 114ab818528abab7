//! The four-mirror relay scene: 3-D ray tracing of a beam through four tilted circular
//! mirrors on a rectangle, imaged by one camera at one of eight stations.
//!
//! The frame shows a Gaussian spot where the beam meets the camera's sensor, a speckle cloud
//! with no clear spot when mirror apertures clip part of the beam, and only background and
//! noise when no light arrives. Submodules: `geometry` (vectors), `layout` (where things
//! are), `trace` (mirror hits and clipping), `camera` (stations and placement error),
//! with the speckle pattern from the crate's `speckle` module.

mod camera;
mod geometry;
mod layout;
mod trace;

pub use camera::{CameraPose, Station, UnknownStation};
pub use trace::MirrorTruth;

use layout::Layout;
use trace::{Trace, trace};

use crate::frame::Frame;
use crate::math::{SPOT_EXTENT, gaussian_fraction, gaussian_profile, spot_span};
use crate::profile::BeamShape;
use crate::readout::{Readout, mix64, scene_key};
use crate::scenario::{RelayParams, ScenarioError};
use crate::sensor::{FrameDraw, Sensor};
use crate::speckle::SpeckleTile;

/// What a camera at one station (at its calibrated pose) would receive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StationTruth {
    /// Fraction of the input power arriving at the station's plane.
    pub power: f64,
    /// Fraction of the input power landing on the sensor.
    pub power_on_sensor: f64,
    /// Where the beam centre meets the station plane, mm from the sensor centre (x right,
    /// y down); `None` when no light arrives or the ray never crosses the plane.
    pub hit_mm: Option<[f64; 2]>,
    /// The same point in pixels from the image centre.
    pub offset_px: Option<[f64; 2]>,
    /// `power_on_sensor` reaches the light threshold: the camera sees light.
    pub lit: bool,
}

/// Hidden truth of one relay state, for scoring only.
#[derive(Debug, Clone, PartialEq)]
pub struct RelayTruth {
    /// M1..M4: whether light reached each mirror, where, and how much it clipped.
    pub mirrors: [MirrorTruth; 4],
    /// C1..C8 at their calibrated poses.
    pub stations: [StationTruth; 8],
    /// Beam centre at C8 in pixels from the image centre, when light reaches C8's sensor.
    pub c8_offset_px: Option<[f64; 2]>,
}

/// Ray tracing and truth, without the rendering state (cheap to build).
#[derive(Debug, Clone)]
struct Optics {
    params: RelayParams,
    layout: Layout,
}

impl Optics {
    fn new(params: RelayParams) -> Self {
        let layout = Layout::new(&params);
        Self { params, layout }
    }

    fn trace(&self, offsets: &[i32; 8], shaft: &[i32]) -> Trace {
        assert_eq!(
            shaft.len(),
            Relay::AXES,
            "the relay takes {} axes",
            Relay::AXES
        );
        let scale = self.params.tilt_rad_per_step;
        let tilts = std::array::from_fn(|a| (f64::from(shaft[a]) + f64::from(offsets[a])) * scale);
        trace(&self.params, &self.layout, &tilts)
    }

    fn truth(&self, offsets: &[i32; 8], shaft: &[i32]) -> RelayTruth {
        let t = self.trace(offsets, shaft);
        let p = &self.params;
        let pitch = p.pixel_pitch_mm();
        let half = [
            p.camera.sensor_width_mm / 2.0,
            p.camera.sensor_height_mm / 2.0,
        ];
        let sigma = p.beam_radius_mm / 2.0;
        let stations = std::array::from_fn(|i| {
            let beam = t.beams[i / 2];
            let hit = beam.and_then(|b| self.layout.stations[i].intersect(&b.ray));
            let power = beam.map_or(0.0, |b| b.power);
            let power_on_sensor = hit.map_or(0.0, |[u, v]| {
                power
                    * gaussian_fraction(u, sigma, -half[0], half[0])
                    * gaussian_fraction(v, sigma, -half[1], half[1])
            });
            StationTruth {
                power,
                power_on_sensor,
                hit_mm: hit,
                offset_px: hit.map(|[u, v]| [u / pitch[0], v / pitch[1]]),
                lit: power_on_sensor >= p.light_threshold && power_on_sensor > 0.0,
            }
        });
        let c8: &StationTruth = &stations[7];
        RelayTruth {
            mirrors: t.mirrors,
            c8_offset_px: if c8.lit { c8.offset_px } else { None },
            stations,
        }
    }

    /// No light can show at C8, even with a camera placement error: the beam is lost, or it
    /// meets C8's plane farther from the sensor than any spot or speckle cloud reaches.
    fn c8_dark(&self, offsets: &[i32; 8]) -> bool {
        let truth = self.truth(offsets, &[0; 8]);
        let p = &self.params;
        let reach = SPOT_EXTENT * p.speckle.spread.max(1.0) * p.beam_radius_mm
            + 5.0 * p.camera.placement_position_std_mm;
        truth.stations[7].hit_mm.is_none_or(|[u, v]| {
            u.abs() > p.camera.sensor_width_mm / 2.0 + reach
                || v.abs() > p.camera.sensor_height_mm / 2.0 + reach
        })
    }
}

/// Whether no light shows at C8 with the shafts at zero, for offsets drawn by the seeds.
pub(crate) fn starts_dark(params: &RelayParams, offsets: &[i32; 8]) -> bool {
    Optics::new(params.clone()).c8_dark(offsets)
}

/// A relay scene with fixed hidden offsets.
#[derive(Debug, Clone)]
pub struct Relay {
    optics: Optics,
    offsets: [i32; 8],
    key: u64,
    speckle: SpeckleTile,
    spot: BeamShape,
    sensor: Sensor,
}

impl Relay {
    /// Number of motor axes: for mirror m = 0..3, axis 2m tilts it vertically and axis 2m+1
    /// horizontally.
    pub const AXES: usize = 8;

    /// A scene whose beam runs along the nominal path when the shafts read `-offsets`.
    pub fn new(params: RelayParams, offsets: [i32; 8]) -> Result<Self, ScenarioError> {
        params.validate()?;
        let key = scene_key(params.noise.seed, &offsets);
        let speckle = SpeckleTile::new(params.speckle.grain_px, mix64(params.noise.seed));
        let pitch = params.pixel_pitch_mm();
        let realism = &params.realism;
        let spot = BeamShape::new(
            &realism.beam_profile,
            &realism.texture,
            [
                params.beam_radius_mm / pitch[0],
                params.beam_radius_mm / pitch[1],
            ],
            realism.orientation(),
            mix64(params.noise.seed ^ 1),
        )
        .map_err(|reason| ScenarioError::Invalid {
            field: "relay.realism.beam_profile".into(),
            reason,
        })?;
        let sensor = Sensor::new(
            realism,
            params.camera.width_px as usize,
            params.camera.height_px as usize,
            key,
        )
        .map_err(|reason| ScenarioError::Invalid {
            field: "relay.realism.background_photo".into(),
            reason,
        })?;
        Ok(Self {
            optics: Optics::new(params),
            offsets,
            key,
            speckle,
            spot,
            sensor,
        })
    }

    /// The parameters this scene was built with.
    pub fn params(&self) -> &RelayParams {
        &self.optics.params
    }

    /// The hidden truth for the given shaft positions, stations at their calibrated poses.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn truth(&self, shaft: &[i32]) -> RelayTruth {
        self.optics.truth(&self.offsets, shaft)
    }

    /// Renders what the camera at `pose` sees for the given shaft positions; `frame_index`
    /// selects the noise.
    ///
    /// # Panics
    /// If `shaft` does not hold [`Self::AXES`] values.
    pub fn render(&self, shaft: &[i32], pose: &CameraPose, frame_index: u64) -> Frame {
        let p = &self.optics.params;
        let (w, h) = (p.camera.width_px as usize, p.camera.height_px as usize);
        let readout = Readout::new(&p.noise, self.key, frame_index);
        let trace = self.optics.trace(&self.offsets, shaft);
        let plane = self.optics.layout.stations[pose.station.index()]
            .perturbed(pose.offset_mm, pose.rotation_rad);
        let lit = trace.beams[pose.station.segment()]
            .and_then(|beam| plane.intersect(&beam.ray).map(|hit| (beam, hit)));
        let Some((beam, [u, v])) = lit else {
            let pixels = self.sensor.expose(&readout, |_, _| false);
            return Frame::deep(
                p.camera.width_px,
                p.camera.height_px,
                pixels,
                readout.full_scale(),
            )
            .expect("buffer sized to the frame");
        };

        let draw = FrameDraw::new(&p.realism, self.key, frame_index);
        let pitch = p.pixel_pitch_mm();
        let o = p.realism.orientation();
        let d = [u / pitch[0], v / pitch[1]];
        let centre = [
            w as f64 / 2.0 + o[0][0] * d[0] + o[0][1] * d[1] + draw.jitter[0][0],
            h as f64 / 2.0 + o[1][0] * d[0] + o[1][1] * d[1] + draw.jitter[0][1],
        ];
        let radius = [p.beam_radius_mm / pitch[0], p.beam_radius_mm / pitch[1]];
        // Light lost upstream on a mirror edge, or falling past the sensor's edge, scatters:
        // the more is lost, the more of what remains shows as speckle instead of a spot.
        let sigma = p.beam_radius_mm / 2.0;
        let half = [
            p.camera.sensor_width_mm / 2.0,
            p.camera.sensor_height_mm / 2.0,
        ];
        let on_sensor = gaussian_fraction(u, sigma, -half[0], half[0])
            * gaussian_fraction(v, sigma, -half[1], half[1]);
        let lost = 1.0 - beam.power * on_sensor;
        let clean = (-(lost / p.speckle.clip_tolerance).powi(2)).exp();
        let spot = self.spot.place(centre, [w, h]);
        let spot_peak = (p.spot_peak_level * beam.power * clean * draw.gain) as f32;
        let cloud_radius = radius.map(|r| r * p.speckle.spread);
        let cloud = Layer::new(
            centre,
            cloud_radius,
            p.speckle.level * beam.power * (1.0 - clean) * draw.gain,
            [w, h],
        );
        // The speckle pattern moves with the cloud and changes with the clipping geometry.
        let shift = [
            (beam.clip_key & 0xffff) as isize - centre[0].round() as isize,
            ((beam.clip_key >> 32) & 0xffff) as isize - centre[1].round() as isize,
        ];

        let mut scratch = vec![0f32; w];
        let pixels = self.sensor.expose(&readout, |y, row| {
            let mut lit =
                spot_peak > 0.0 && spot.add_intensity_row(y, spot_peak, &mut scratch, row);
            if let Some(a) = cloud.row(y) {
                let ty = (y as isize).wrapping_add(shift[1]) as usize;
                for ((x, s), g) in cloud
                    .cols
                    .clone()
                    .zip(&mut row[cloud.cols.clone()])
                    .zip(&cloud.gx)
                {
                    let tx = (x as isize).wrapping_add(shift[0]) as usize;
                    *s += a * g * self.speckle.at(tx, ty);
                }
                lit = true;
            }
            lit
        });
        Frame::deep(
            p.camera.width_px,
            p.camera.height_px,
            pixels,
            readout.full_scale(),
        )
        .expect("buffer sized to the frame")
    }
}

/// A separable Gaussian-envelope layer of the relay image, restricted to where it is bright
/// enough to matter.
struct Layer {
    cols: std::ops::Range<usize>,
    rows: std::ops::Range<usize>,
    gx: Vec<f32>,
    gy: Vec<f32>,
    peak: f32,
}

impl Layer {
    /// Faintest peak worth drawing, gray levels.
    const MIN_PEAK: f64 = 0.01;

    fn new(centre: [f64; 2], radius: [f64; 2], peak: f64, size: [usize; 2]) -> Self {
        let visible = peak >= Self::MIN_PEAK;
        let span = |axis: usize| {
            if visible {
                spot_span(centre[axis], radius[axis], size[axis])
            } else {
                0..0
            }
        };
        let (cols, rows) = (span(0), span(1));
        Self {
            gx: gaussian_profile(centre[0], radius[0], cols.clone()),
            gy: gaussian_profile(centre[1], radius[1], rows.clone()),
            cols,
            rows,
            peak: peak as f32,
        }
    }

    /// The row factor (peak included) of row `y`, or `None` where the layer is absent.
    fn row(&self, y: usize) -> Option<f32> {
        if self.cols.is_empty() || !self.rows.contains(&y) {
            None
        } else {
            Some(self.peak * self.gy[y - self.rows.start])
        }
    }
}
