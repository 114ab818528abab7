//! Parameters of the four-mirror relay scene (`[relay]`).

use serde::{Deserialize, Serialize};

use super::check::Check;
use super::{NoiseParams, RealismParams, ScenarioError};

/// The relay scene: an input beam turned 90 degrees in the table plane by each of four
/// circular mirrors M1..M4 laid out on a rectangle, observed by one camera at one of eight
/// stations C1..C8 (two per segment: C1, C2 after M1; C3, C4 after M2; C5, C6 after M3;
/// C7, C8 after M4).
///
/// Axis order (8 axes): axis 2m is mirror m's vertical tilt, axis 2m+1 its horizontal tilt,
/// for m = 0..3 (M1..M4). A mirror tilts by (shaft + offset) x `tilt_rad_per_step` and the beam
/// turns by twice that.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelayParams {
    /// Length of the segments M1->M2 and M3->M4, mm. Default 279.4 (11 inches).
    pub long_side_mm: f64,
    /// Length of the segment M2->M3, mm. Default 203.2 (8 inches).
    pub short_side_mm: f64,
    /// Diameter of each circular mirror, mm. Default 25.4 (1 inch).
    pub mirror_diameter_mm: f64,
    /// 1/e^2 intensity radius of the collimated beam, mm. Default 1.0.
    pub beam_radius_mm: f64,
    /// Mirror tilt per motor step, rad. Default 0.027 / 4096 (0.027 rad per revolution).
    pub tilt_rad_per_step: f64,
    /// Hidden offsets are uniform in +-this many steps on every axis (redrawn until no light
    /// reaches C8). Default 10000.
    pub offset_range_steps: i32,
    /// Distance of C1..C8 from the mirror that starts their segment, mm, along the nominal
    /// path. Default `[25, 254.4, 25, 178.2, 25, 254.4, 25, 300]`: C1, C3, C5, C7 25 mm after
    /// their mirror, C2, C4, C6 25 mm before the next mirror, C8 300 mm after M4.
    pub station_distances_mm: [f64; 8],
    /// Fraction of the input power below which the beam counts as lost: it carries no light
    /// downstream and the station shows a dark frame. Default 0.001.
    pub light_threshold: f64,
    /// Peak gray level of an unclipped beam spot. Default 220.
    pub spot_peak_level: f64,
    /// The camera carried between stations.
    pub camera: RelayCameraParams,
    /// Appearance of a clipped beam.
    pub speckle: SpeckleParams,
    /// Camera read-out.
    pub noise: NoiseParams,
    /// Realism layers (the spot's shape, flicker, jitter, camera effects, the same at every
    /// station). All off by default.
    pub realism: RealismParams,
}

/// The camera moved between the stations, and how precisely it is placed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct RelayCameraParams {
    /// Image width in pixels. Default 640.
    pub width_px: u32,
    /// Image height in pixels. Default 480.
    pub height_px: u32,
    /// Sensor width, mm; the field of view at the station plane. Default 6.4.
    pub sensor_width_mm: f64,
    /// Sensor height, mm. Default 4.8.
    pub sensor_height_mm: f64,
    /// Standard deviation of the camera position error per axis at each placement, mm.
    /// Default 0.1.
    pub placement_position_std_mm: f64,
    /// Standard deviation of the camera rotation error about each axis at each placement,
    /// degrees. Default 0.5.
    pub placement_rotation_std_deg: f64,
}

/// How a partly clipped beam looks: a speckle cloud with no clear spot.
///
/// With `p` the fraction of the input power reaching the camera and `k = 1 - p` the fraction
/// lost on mirror edges, the clean spot is weighted by `p exp(-(k / clip_tolerance)^2)` and the
/// speckle cloud by `p (1 - exp(-(k / clip_tolerance)^2))`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SpeckleParams {
    /// Correlation length of the speckle grains, px. Default 2.5.
    pub grain_px: f64,
    /// Radius of the speckle cloud relative to the beam radius. Default 2.5.
    pub spread: f64,
    /// Mean gray level at the cloud's centre (grains reach several times this). Default 45.
    pub level: f64,
    /// Lost power fraction at which the clean spot has faded to 1/e. Default 0.15.
    pub clip_tolerance: f64,
}

impl Default for RelayParams {
    fn default() -> Self {
        Self {
            long_side_mm: 279.4,
            short_side_mm: 203.2,
            mirror_diameter_mm: 25.4,
            beam_radius_mm: 1.0,
            tilt_rad_per_step: 0.027 / 4096.0,
            offset_range_steps: 10000,
            station_distances_mm: [25.0, 254.4, 25.0, 178.2, 25.0, 254.4, 25.0, 300.0],
            light_threshold: 1e-3,
            spot_peak_level: 220.0,
            camera: RelayCameraParams::default(),
            speckle: SpeckleParams::default(),
            noise: NoiseParams::default(),
            realism: RealismParams::default(),
        }
    }
}

impl Default for RelayCameraParams {
    fn default() -> Self {
        Self {
            width_px: 640,
            height_px: 480,
            sensor_width_mm: 6.4,
            sensor_height_mm: 4.8,
            placement_position_std_mm: 0.1,
            placement_rotation_std_deg: 0.5,
        }
    }
}

impl Default for SpeckleParams {
    fn default() -> Self {
        Self {
            grain_px: 2.5,
            spread: 2.5,
            level: 45.0,
            clip_tolerance: 0.15,
        }
    }
}

impl RelayParams {
    /// Checks every field; the error names the first bad one as `relay.<field>`.
    pub fn validate(&self) -> Result<(), ScenarioError> {
        let check = Check::new("relay");
        check.gt("long_side_mm", self.long_side_mm, 0.0)?;
        check.gt("short_side_mm", self.short_side_mm, 0.0)?;
        check.gt("mirror_diameter_mm", self.mirror_diameter_mm, 0.0)?;
        check.gt("beam_radius_mm", self.beam_radius_mm, 0.0)?;
        check.gt("tilt_rad_per_step", self.tilt_rad_per_step, 0.0)?;
        check.offset_range("offset_range_steps", self.offset_range_steps)?;
        for (i, &d) in self.station_distances_mm.iter().enumerate() {
            let field = format!("station_distances_mm[{i}]");
            match self.segment_length_mm(i / 2) {
                Some(len) => check.within(&field, d, f64::MIN_POSITIVE, len)?,
                None => check.gt(&field, d, 0.0)?,
            }
        }
        check.within("light_threshold", self.light_threshold, 0.0, 1.0)?;
        check.ge("spot_peak_level", self.spot_peak_level, 0.0)?;

        let camera = Check::new("relay.camera");
        camera.image_size(self.camera.width_px, self.camera.height_px)?;
        camera.gt("sensor_width_mm", self.camera.sensor_width_mm, 0.0)?;
        camera.gt("sensor_height_mm", self.camera.sensor_height_mm, 0.0)?;
        camera.within(
            "placement_position_std_mm",
            self.camera.placement_position_std_mm,
            0.0,
            10.0,
        )?;
        camera.within(
            "placement_rotation_std_deg",
            self.camera.placement_rotation_std_deg,
            0.0,
            10.0,
        )?;

        let speckle = Check::new("relay.speckle");
        speckle.within("grain_px", self.speckle.grain_px, 0.5, 16.0)?;
        speckle.gt("spread", self.speckle.spread, 0.0)?;
        speckle.ge("level", self.speckle.level, 0.0)?;
        speckle.gt("clip_tolerance", self.speckle.clip_tolerance, 0.0)?;
        self.noise.validate("relay.noise")?;
        self.realism.validate("relay.realism")
    }

    /// Length of segment `s` (0: M1->M2, 1: M2->M3, 2: M3->M4); `None` for the open output.
    pub(crate) fn segment_length_mm(&self, segment: usize) -> Option<f64> {
        match segment {
            0 | 2 => Some(self.long_side_mm),
            1 => Some(self.short_side_mm),
            _ => None,
        }
    }

    /// Sensor pixel pitch (x, y), mm per px.
    pub(crate) fn pixel_pitch_mm(&self) -> [f64; 2] {
        [
            self.camera.sensor_width_mm / f64::from(self.camera.width_px),
            self.camera.sensor_height_mm / f64::from(self.camera.height_px),
        ]
    }
}
