//! The realism layers every scene can add on top of its plain model (`[<scene>.realism]`):
//! the beam's shape and texture, laser power flicker and pointing jitter, and what a real
//! camera adds (ambient light and a sloping background, hot pixels, stationary stray spots,
//! a read-out smear column, a photograph as the stationary background, the sensor's rotation
//! and a mirrored image). Every layer is off by default, so a scene without the table renders
//! exactly as before.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::ScenarioError;
use super::check::Check;

/// The shape of a beam's intensity profile. Every profile has its intensity centroid (the
/// ISO 11146 first moment) at the beam's centre, is scaled by the scene's beam radius and
/// peaks at the scene's peak level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum BeamProfile {
    /// A round Gaussian (TEM00) of 1/e² radius w: the default.
    #[default]
    Gaussian,
    /// An elliptical Gaussian: 1/e² radii `axes[0]·w` and `axes[1]·w` along its own axes,
    /// the first turned `angle_deg` from image +x towards +y.
    Elliptical { axes: [f64; 2], angle_deg: f64 },
    /// A Hermite-Gaussian mode TEM_mn of waist w (TEM01: two lobes side by side along y,
    /// TEM10 along x), turned `angle_deg`. Its lobes alternate in field sign, so fringes shift
    /// by half a period from lobe to lobe where it interferes.
    HermiteGauss { m: u32, n: u32, angle_deg: f64 },
    /// A doughnut (Laguerre-Gaussian LG01): a bright ring of radius about 0.7 w, dark centre.
    Donut,
    /// A flat top: a super-Gaussian exp(-2 (r/w)^order); order 2 is a Gaussian, 8 to 20 a
    /// flat disc with a soft edge.
    TopHat { order: f64 },
    /// A grayscale photograph of a real beam (PNG, JPEG or TIFF, 8 or 16 bit), or the part
    /// `crop = [x, y, width, height]` (px) of it that holds the beam (the rest of the photo,
    /// ghosts and glow, does not move with the beam), background-subtracted, centred on its
    /// intensity centroid and scaled so its second-moment radius equals w. A relative path
    /// is taken from the scenario file's folder.
    Image {
        path: PathBuf,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        crop: Option<[u32; 4]>,
    },
}

impl BeamProfile {
    /// The short name used by sweeps and tables.
    pub fn name(&self) -> &'static str {
        match self {
            Self::Gaussian => "gaussian",
            Self::Elliptical { .. } => "elliptical",
            Self::HermiteGauss { .. } => "hermite_gauss",
            Self::Donut => "donut",
            Self::TopHat { .. } => "top_hat",
            Self::Image { .. } => "image",
        }
    }

    fn validate(&self, check: &Check, field: &str) -> Result<(), ScenarioError> {
        match self {
            Self::Gaussian | Self::Donut => Ok(()),
            Self::Elliptical { axes, angle_deg } => {
                check.within(&format!("{field}.axes[0]"), axes[0], 0.05, 20.0)?;
                check.within(&format!("{field}.axes[1]"), axes[1], 0.05, 20.0)?;
                check.finite(&format!("{field}.angle_deg"), *angle_deg)
            }
            Self::HermiteGauss { m, n, angle_deg } => {
                check.within(&format!("{field}.m"), f64::from(*m), 0.0, 8.0)?;
                check.within(&format!("{field}.n"), f64::from(*n), 0.0, 8.0)?;
                check.finite(&format!("{field}.angle_deg"), *angle_deg)
            }
            Self::TopHat { order } => check.within(&format!("{field}.order"), *order, 2.0, 50.0),
            Self::Image { path, crop } => crate::profile::load_profile_image(path, *crop)
                .map(|_| ())
                .map_err(|reason| ScenarioError::Invalid {
                    field: check.path(&format!("{field}.path")),
                    reason,
                }),
        }
    }
}

/// Structure inside the beam that moves with it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum Texture {
    /// A smooth beam: the default.
    #[default]
    None,
    /// Straight etalon fringes from a window or filter in the beam path: intensity times
    /// `1 + contrast · cos(2π s / period_px)`, s along `angle_deg`.
    Etalon {
        contrast: f64,
        period_px: f64,
        angle_deg: f64,
    },
    /// Speckle from a diffuser or dirty optics: intensity times a speckle pattern of mean 1,
    /// blended as `1 - contrast + contrast · speckle`.
    Speckle { contrast: f64, grain_px: f64 },
}

impl Texture {
    fn validate(&self, check: &Check) -> Result<(), ScenarioError> {
        match self {
            Self::None => Ok(()),
            Self::Etalon {
                contrast,
                period_px,
                angle_deg,
            } => {
                check.within("texture.contrast", *contrast, 0.0, 1.0)?;
                check.within("texture.period_px", *period_px, 2.0, 10_000.0)?;
                check.finite("texture.angle_deg", *angle_deg)
            }
            Self::Speckle { contrast, grain_px } => {
                check.within("texture.contrast", *contrast, 0.0, 1.0)?;
                check.within("texture.grain_px", *grain_px, 0.5, 16.0)
            }
        }
    }
}

/// A stationary spot of light on the image that no motor moves (a ghost reflection, a
/// stray beam, a lamp): the agent must tell it from the beam by its not moving.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct StraySpot {
    /// Centre relative to the image centre, px (x right, y down). Default `[0, 0]`.
    pub centre_offset_px: [f64; 2],
    /// 1/e² radius, px. Default 40.
    pub radius_px: f64,
    /// Peak gray level. Default 60.
    pub peak_level: f64,
}

impl Default for StraySpot {
    fn default() -> Self {
        Self {
            centre_offset_px: [0.0, 0.0],
            radius_px: 40.0,
            peak_level: 60.0,
        }
    }
}

/// A photograph as the light that stays put on the camera (its dark level, glow, ghosts),
/// stretched over the frame and added to the scene's light at its own precision.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BackgroundPhoto {
    /// The photograph (PNG, JPEG or TIFF, 8 or 16 bit); a relative path is taken from the
    /// scenario file's folder.
    pub path: PathBuf,
    /// Boxes `[x, y, width, height]` (photo px) filled in from their rims: the photographed
    /// beam, which would otherwise stay put as a bright spot. Default none.
    #[serde(default)]
    pub erase: Vec<[u32; 4]>,
    /// Factor on the photograph's gray levels. Default 1.
    #[serde(default = "unit_gain")]
    pub gain: f64,
}

fn unit_gain() -> f64 {
    1.0
}

/// `path` taken from `base` when it is relative.
fn resolved(path: &mut PathBuf, base: &Path) {
    if path.is_relative() {
        *path = base.join(&*path);
    }
}

/// The realism layers of one scene. All off by default.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
#[serde(default, deny_unknown_fields)]
pub struct RealismParams {
    /// Shape of the beams: the Michelson's beam 1 (and beam 2 unless `second_beam_profile`
    /// is given), the cavity's primary and secondary, the relay's spot. Default gaussian.
    pub beam_profile: BeamProfile,
    /// The Michelson's beam 2, when it differs from beam 1 (other scenes ignore it).
    pub second_beam_profile: Option<BeamProfile>,
    /// Texture inside the beams, moving with them. Default none.
    pub texture: Texture,
    /// Relative standard deviation of the laser power from one frame to the next (0.1 is
    /// 10 %): every beam and everything lit by the laser scales together. Default 0.
    pub power_flicker: f64,
    /// Standard deviation of each beam's random displacement per frame and image axis, px
    /// (air currents, vibration). Default 0.
    pub pointing_jitter_px: f64,
    /// Uniform light from the room on top of the dark level, gray levels. Default 0.
    pub ambient_level: f64,
    /// A background sloping across the frame: gray levels added at the right and the bottom
    /// edge (and taken away at the left and the top), 0 at the centre. Default `[0, 0]`.
    pub gradient_levels: [f64; 2],
    /// Number of hot pixels (stuck bright, fixed places). Default 0.
    pub hot_pixels: u32,
    /// Gray level of a hot pixel above the dark level. Default 200.
    pub hot_pixel_level: f64,
    /// Read-out smear: each pixel of a column gains this share of the column's mean light
    /// (a bright spot draws a vertical streak through the whole frame). Default 0.
    pub smear: f64,
    /// Stationary spots of stray light. Default none.
    pub stray_spots: Vec<StraySpot>,
    /// A photograph as the stationary background. Default none.
    pub background_photo: Option<BackgroundPhoto>,
    /// The camera turned about its optical axis, degrees (image +x towards +y). Every motion
    /// and shape on the image turns with it. Default 0.
    pub camera_rotation_deg: f64,
    /// The image mirrored left-right (a camera seen through a mirror, or a flipped read-out).
    /// Default false.
    pub camera_flip: bool,
}

impl RealismParams {
    /// Checks every field; errors name `<prefix>.<field>`.
    pub(crate) fn validate(&self, prefix: &str) -> Result<(), ScenarioError> {
        let check = Check::new(prefix);
        self.beam_profile.validate(&check, "beam_profile")?;
        if let Some(profile) = &self.second_beam_profile {
            profile.validate(&check, "second_beam_profile")?;
        }
        self.texture.validate(&check)?;
        check.within("power_flicker", self.power_flicker, 0.0, 0.5)?;
        check.within("pointing_jitter_px", self.pointing_jitter_px, 0.0, 100.0)?;
        check.within("ambient_level", self.ambient_level, 0.0, 255.0)?;
        check.within("gradient_levels[0]", self.gradient_levels[0], -255.0, 255.0)?;
        check.within("gradient_levels[1]", self.gradient_levels[1], -255.0, 255.0)?;
        check.within("hot_pixels", f64::from(self.hot_pixels), 0.0, 1e6)?;
        check.within("hot_pixel_level", self.hot_pixel_level, 0.0, 1e4)?;
        check.within("smear", self.smear, 0.0, 10.0)?;
        for (i, spot) in self.stray_spots.iter().enumerate() {
            let field = |name: &str| format!("stray_spots[{i}].{name}");
            check.finite(&field("centre_offset_px[0]"), spot.centre_offset_px[0])?;
            check.finite(&field("centre_offset_px[1]"), spot.centre_offset_px[1])?;
            check.within(&field("radius_px"), spot.radius_px, 0.5, 10_000.0)?;
            check.within(&field("peak_level"), spot.peak_level, 0.0, 1e5)?;
        }
        if let Some(photo) = &self.background_photo {
            check.within("background_photo.gain", photo.gain, 0.0, 100.0)?;
            crate::photo::Photo::load(&photo.path)
                .and_then(|p| p.erased(&photo.erase))
                .map_err(|reason| ScenarioError::Invalid {
                    field: check.path("background_photo"),
                    reason,
                })?;
        }
        check.finite("camera_rotation_deg", self.camera_rotation_deg)
    }

    /// Takes every relative photo path from `base` (the scenario file's folder).
    pub fn resolve_paths(&mut self, base: &Path) {
        for profile in
            std::iter::once(&mut self.beam_profile).chain(self.second_beam_profile.as_mut())
        {
            if let BeamProfile::Image { path, .. } = profile {
                resolved(path, base);
            }
        }
        if let Some(photo) = &mut self.background_photo {
            resolved(&mut photo.path, base);
        }
    }

    /// The profile of beam `k` (only the Michelson has a second beam).
    pub fn profile(&self, k: usize) -> &BeamProfile {
        match (k, &self.second_beam_profile) {
            (1, Some(second)) => second,
            _ => &self.beam_profile,
        }
    }

    /// The camera's orientation as a 2 x 2 matrix taking a displacement in the scene's own
    /// image axes to the displayed image: the flip, then the rotation.
    pub fn orientation(&self) -> [[f64; 2]; 2] {
        let (s, c) = self.camera_rotation_deg.to_radians().sin_cos();
        let f = if self.camera_flip { -1.0 } else { 1.0 };
        [[c * f, -s], [s * f, c]]
    }
}
