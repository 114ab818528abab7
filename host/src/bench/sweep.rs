//! Difficulty sweeps: one scenario knob varied over a list of values, to find where each
//! method breaks. Every knob maps onto scenario fields; a value that makes the scenario
//! invalid is an error naming the knob, the value and the field. Each knob has standard
//! values (what `--sweep all` runs) and documented harsh values, where the vision agent is
//! expected to hold.

use optalign_optics::scenario::{BeamProfile, RealismParams, StraySpot, Texture};

use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// A scenario knob a sweep can vary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Knob {
    /// Camera read-noise standard deviation of every scene, gray levels.
    Noise,
    /// True mount dead band, steps (the firmware's compensation keeps its configured value).
    Backlash,
    /// Factor on every hidden-offset range.
    OffsetScale,
    /// Factor on the cavity's stationary artefacts (ring, halo, ghosts).
    ArtefactBrightness,
    /// Factor on the relay camera's placement errors (position and rotation).
    PlacementError,
    /// Factor on the motor response: Michelson and cavity sensitivity matrices, relay tilt
    /// per step.
    SensitivityScale,
    /// Off-diagonal response as a fraction of the diagonal (Michelson and cavity), keeping
    /// the default signs.
    CrossCoupling,
    /// The beams' profile, by name (see [`PROFILES`]).
    BeamProfile,
    /// Contrast of etalon fringes inside the beams (period 0.35 beam radii).
    Texture,
    /// Relative standard deviation of the laser power from frame to frame.
    Flicker,
    /// Standard deviation of each beam's displacement per frame and axis, px.
    Jitter,
    /// Number of hot pixels.
    HotPixels,
    /// Number of stationary stray spots, each about as large and bright as the beam.
    StraySpots,
    /// Uniform ambient light, gray levels.
    Ambient,
    /// A background sloping left to right and top to bottom, gray levels at the edges.
    Gradient,
    /// Read-out smear: share of a column's mean light added along it.
    Smear,
    /// The camera turned about its axis, degrees.
    CameraRotation,
    /// The image mirrored left-right: 0 or 1.
    CameraFlip,
    /// Amplitude of the screws' periodic pitch error, steps.
    PitchError,
    /// Elastic hysteresis of the screws beyond the dead band, steps either side.
    Hysteresis,
    /// RMS wander of the Michelson's fringe phase from frame to frame, radians.
    FringeDrift,
}

/// The named beam profiles of the `beam_profile` knob, in value order (0, 1, ...).
pub const PROFILES: [&str; 6] = [
    "gaussian",
    "elliptical",
    "tem01",
    "tem10",
    "donut",
    "top_hat",
];

/// Where stray spots of the `stray_spots` knob sit, as shares of the image size from the
/// centre.
const STRAY_PLACES: [[f64; 2]; 6] = [
    [0.31, -0.27],
    [-0.36, 0.22],
    [0.12, 0.36],
    [-0.22, -0.33],
    [0.41, 0.29],
    [-0.43, -0.04],
];

impl Knob {
    pub const ALL: [Knob; 21] = [
        Knob::Noise,
        Knob::Backlash,
        Knob::OffsetScale,
        Knob::ArtefactBrightness,
        Knob::PlacementError,
        Knob::SensitivityScale,
        Knob::CrossCoupling,
        Knob::BeamProfile,
        Knob::Texture,
        Knob::Flicker,
        Knob::Jitter,
        Knob::HotPixels,
        Knob::StraySpots,
        Knob::Ambient,
        Knob::Gradient,
        Knob::Smear,
        Knob::CameraRotation,
        Knob::CameraFlip,
        Knob::PitchError,
        Knob::Hysteresis,
        Knob::FringeDrift,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Noise => "noise",
            Self::Backlash => "backlash",
            Self::OffsetScale => "offset_scale",
            Self::ArtefactBrightness => "artefact_brightness",
            Self::PlacementError => "placement_error",
            Self::SensitivityScale => "sensitivity_scale",
            Self::CrossCoupling => "cross_coupling",
            Self::BeamProfile => "beam_profile",
            Self::Texture => "texture",
            Self::Flicker => "flicker",
            Self::Jitter => "jitter",
            Self::HotPixels => "hot_pixels",
            Self::StraySpots => "stray_spots",
            Self::Ambient => "ambient",
            Self::Gradient => "gradient",
            Self::Smear => "smear",
            Self::CameraRotation => "camera_rotation",
            Self::CameraFlip => "camera_flip",
            Self::PitchError => "pitch_error",
            Self::Hysteresis => "hysteresis",
            Self::FringeDrift => "fringe_drift",
        }
    }

    /// The knob's axis label on charts.
    pub fn label(self) -> &'static str {
        match self {
            Self::Noise => "read-noise std (gray levels)",
            Self::Backlash => "true backlash (steps), compensation fixed",
            Self::OffsetScale => "offset range scale",
            Self::ArtefactBrightness => "artefact brightness scale",
            Self::PlacementError => "camera placement error scale",
            Self::SensitivityScale => "motor sensitivity scale",
            Self::CrossCoupling => "cross-coupling (off-diagonal / diagonal)",
            Self::BeamProfile => "beam profile",
            Self::Texture => "etalon fringe contrast inside the beam",
            Self::Flicker => "laser power flicker (relative std per frame)",
            Self::Jitter => "pointing jitter (px std per frame)",
            Self::HotPixels => "hot pixels",
            Self::StraySpots => "stationary stray spots",
            Self::Ambient => "ambient light (gray levels)",
            Self::Gradient => "background slope (gray levels at the edges)",
            Self::Smear => "read-out smear (share of the column light)",
            Self::CameraRotation => "camera rotation (degrees)",
            Self::CameraFlip => "image mirrored (0 or 1)",
            Self::PitchError => "screw pitch error (steps)",
            Self::Hysteresis => "screw hysteresis (steps either side)",
            Self::FringeDrift => "fringe phase wander (rad rms per frame)",
        }
    }

    /// The values `--sweep all` (or `--sweep KNOB` alone) runs: the default first.
    pub fn standard_values(self) -> &'static [f64] {
        match self {
            Self::Noise => &[2.5, 10.0, 30.0, 60.0],
            Self::Backlash => &[30.0, 100.0, 300.0, 1000.0],
            Self::OffsetScale => &[1.0, 0.25, 0.5, 1.25],
            Self::ArtefactBrightness => &[1.0, 3.0, 6.0],
            Self::PlacementError => &[1.0, 0.0, 5.0, 20.0],
            Self::SensitivityScale => &[1.0, 0.25, 0.5, 2.0, 4.0],
            Self::CrossCoupling => &[0.0, 0.2, 0.5, 0.8],
            Self::BeamProfile => &[0.0, 1.0, 2.0, 3.0, 4.0, 5.0],
            Self::Texture => &[0.0, 0.3, 0.6, 0.9],
            Self::Flicker => &[0.0, 0.03, 0.1, 0.2],
            Self::Jitter => &[0.0, 1.0, 3.0, 6.0],
            Self::HotPixels => &[0.0, 200.0, 2000.0, 20000.0],
            Self::StraySpots => &[0.0, 1.0, 3.0, 6.0],
            Self::Ambient => &[0.0, 20.0, 60.0, 100.0],
            Self::Gradient => &[0.0, 20.0, 40.0, 80.0],
            Self::Smear => &[0.0, 0.1, 0.3, 1.0],
            Self::CameraRotation => &[0.0, 30.0, 90.0, 135.0, 180.0],
            Self::CameraFlip => &[0.0, 1.0],
            Self::PitchError => &[0.0, 20.0, 50.0, 100.0],
            Self::Hysteresis => &[0.0, 20.0, 50.0, 100.0],
            Self::FringeDrift => &[0.0, 0.5, 1.5, 3.0],
        }
    }

    /// The harsh values: where the vision agent is required to hold (docs/simulation.md).
    pub fn harsh_values(self) -> &'static [f64] {
        match self {
            Self::Noise => &[60.0],
            Self::Backlash => &[300.0],
            Self::OffsetScale => &[1.25],
            Self::ArtefactBrightness => &[6.0],
            Self::PlacementError => &[5.0],
            Self::SensitivityScale => &[0.25, 4.0],
            Self::CrossCoupling => &[0.8],
            Self::BeamProfile => &[1.0, 2.0, 3.0, 4.0, 5.0],
            Self::Texture => &[0.6],
            Self::Flicker => &[0.1],
            Self::Jitter => &[3.0],
            Self::HotPixels => &[2000.0],
            Self::StraySpots => &[3.0],
            Self::Ambient => &[60.0],
            Self::Gradient => &[40.0],
            Self::Smear => &[0.3],
            Self::CameraRotation => &[135.0],
            Self::CameraFlip => &[1.0],
            Self::PitchError => &[50.0],
            Self::Hysteresis => &[50.0],
            Self::FringeDrift => &[3.0],
        }
    }

    /// Whether the knob changes anything in `task`'s scene or mechanics.
    pub fn applies_to(self, task: TaskKind) -> bool {
        match self {
            Self::ArtefactBrightness => task == TaskKind::Cavity,
            Self::PlacementError => task == TaskKind::Relay,
            Self::CrossCoupling => task != TaskKind::Relay,
            Self::FringeDrift => task == TaskKind::Michelson,
            _ => true,
        }
    }

    pub fn parse(name: &str) -> Result<Self, String> {
        let wanted = name.trim().replace('-', "_");
        Self::ALL
            .into_iter()
            .find(|knob| knob.name() == wanted)
            .ok_or_else(|| {
                format!(
                    "unknown sweep knob {name:?}; knobs: {}",
                    Self::ALL.map(Knob::name).join(", ")
                )
            })
    }

    /// A value as written on the command line: a number, or for `beam_profile` a profile
    /// name.
    pub fn parse_value(self, text: &str) -> Result<f64, String> {
        let text = text.trim();
        if let Some(names) = self.value_names() {
            return names
                .iter()
                .position(|p| *p == text)
                .map(|i| i as f64)
                .ok_or_else(|| {
                    format!(
                        "sweep knob {self}: {text:?} is not one of {}",
                        names.join(", ")
                    )
                });
        }
        text.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| format!("sweep knob {self}: {text:?} is not a number"))
    }

    /// The names of the knob's values when it takes names rather than numbers.
    pub fn value_names(self) -> Option<&'static [&'static str]> {
        (self == Self::BeamProfile).then_some(&PROFILES[..])
    }

    /// A value as tables and charts show it.
    pub fn format_value(self, value: f64) -> String {
        self.value_names()
            .and_then(|names| names.get(value as usize))
            .map_or_else(|| value.to_string(), |name| (*name).to_owned())
    }

    /// The scenario with this knob set to `value`, validated.
    pub fn apply(self, base: &ScenarioFile, value: f64) -> Result<ScenarioFile, String> {
        let fail = |reason: String| {
            format!(
                "sweep knob {}={}: {reason}",
                self.name(),
                self.format_value(value)
            )
        };
        if !value.is_finite() {
            return Err(fail("the value must be a finite number".into()));
        }
        let whole = |what: &str| {
            if value < 0.0 || value.fract() != 0.0 || value > 1e7 {
                Err(fail(format!("{what} must be a whole number >= 0")))
            } else {
                Ok(value as u32)
            }
        };
        let mut s = base.clone();
        match self {
            Self::Noise => {
                s.michelson.noise.std = value;
                s.cavity.noise.std = value;
                s.relay.noise.std = value;
            }
            Self::Backlash => s.mount.backlash_steps = whole("backlash")?,
            Self::OffsetScale => {
                let scale = |range: &mut i32| *range = (f64::from(*range) * value).round() as i32;
                scale(&mut s.michelson.horizontal_offset_range_steps);
                scale(&mut s.michelson.vertical_offset_range_steps);
                scale(&mut s.cavity.x_offset_range_steps);
                scale(&mut s.cavity.y_offset_range_steps);
                scale(&mut s.relay.offset_range_steps);
            }
            Self::ArtefactBrightness => {
                s.cavity.ring.level *= value;
                s.cavity.halo.level *= value;
                for ghost in &mut s.cavity.ghosts {
                    ghost.peak_level *= value;
                }
            }
            Self::PlacementError => {
                s.relay.camera.placement_position_std_mm *= value;
                s.relay.camera.placement_rotation_std_deg *= value;
            }
            Self::SensitivityScale => {
                for matrix in [
                    &mut s.michelson.mirror_1_sensitivity_px_per_step,
                    &mut s.michelson.mirror_2_sensitivity_px_per_step,
                    &mut s.cavity.secondary.sensitivity_px_per_step,
                ] {
                    for entry in matrix.iter_mut().flatten() {
                        *entry *= value;
                    }
                }
                s.relay.tilt_rad_per_step *= value;
            }
            Self::CrossCoupling => {
                for matrix in [
                    &mut s.michelson.mirror_1_sensitivity_px_per_step,
                    &mut s.michelson.mirror_2_sensitivity_px_per_step,
                    &mut s.cavity.secondary.sensitivity_px_per_step,
                ] {
                    let sign = |v: f64| if v < 0.0 { -1.0 } else { 1.0 };
                    matrix[0][1] = sign(matrix[0][1]) * value * matrix[0][0].abs();
                    matrix[1][0] = sign(matrix[1][0]) * value * matrix[1][1].abs();
                }
            }
            Self::BeamProfile => {
                let profile = match PROFILES.get(value as usize).copied() {
                    Some(_) if value.fract() != 0.0 => None,
                    Some("gaussian") => Some(BeamProfile::Gaussian),
                    Some("elliptical") => Some(BeamProfile::Elliptical {
                        axes: [1.0, 0.6],
                        angle_deg: 30.0,
                    }),
                    Some("tem01") => Some(BeamProfile::HermiteGauss {
                        m: 0,
                        n: 1,
                        angle_deg: 0.0,
                    }),
                    Some("tem10") => Some(BeamProfile::HermiteGauss {
                        m: 1,
                        n: 0,
                        angle_deg: 0.0,
                    }),
                    Some("donut") => Some(BeamProfile::Donut),
                    Some("top_hat") => Some(BeamProfile::TopHat { order: 10.0 }),
                    _ => None,
                };
                let profile = profile
                    .ok_or_else(|| fail(format!("use a profile name: {}", PROFILES.join(", "))))?;
                each_scene(&mut s, |realism, _| {
                    realism.beam_profile = profile.clone();
                    realism.second_beam_profile = None;
                });
            }
            Self::Texture => each_scene(&mut s, |realism, scene| {
                realism.texture = if value == 0.0 {
                    Texture::None
                } else {
                    Texture::Etalon {
                        contrast: value,
                        period_px: (0.35 * scene.radius_px).max(3.0),
                        angle_deg: 60.0,
                    }
                };
            }),
            Self::Flicker => each_scene(&mut s, |realism, _| realism.power_flicker = value),
            Self::Jitter => each_scene(&mut s, |realism, _| realism.pointing_jitter_px = value),
            Self::HotPixels => {
                let count = whole("the number of hot pixels")?;
                each_scene(&mut s, |realism, _| realism.hot_pixels = count);
            }
            Self::StraySpots => {
                let count = whole("the number of stray spots")? as usize;
                if count > STRAY_PLACES.len() {
                    return Err(fail(format!("at most {} stray spots", STRAY_PLACES.len())));
                }
                each_scene(&mut s, |realism, scene| {
                    realism.stray_spots = STRAY_PLACES[..count]
                        .iter()
                        .map(|share| StraySpot {
                            centre_offset_px: [share[0] * scene.size[0], share[1] * scene.size[1]],
                            radius_px: 0.8 * scene.radius_px,
                            peak_level: 0.8 * scene.peak,
                        })
                        .collect();
                });
            }
            Self::Ambient => each_scene(&mut s, |realism, _| realism.ambient_level = value),
            Self::Gradient => each_scene(&mut s, |realism, _| {
                realism.gradient_levels = [value, 0.6 * value];
            }),
            Self::Smear => each_scene(&mut s, |realism, _| realism.smear = value),
            Self::CameraRotation => {
                each_scene(&mut s, |realism, _| realism.camera_rotation_deg = value);
            }
            Self::CameraFlip => {
                if value != 0.0 && value != 1.0 {
                    return Err(fail("write 0 (as is) or 1 (mirrored)".into()));
                }
                each_scene(&mut s, |realism, _| realism.camera_flip = value == 1.0);
            }
            Self::PitchError => s.mount.pitch_error_steps = whole("the pitch error")?,
            Self::Hysteresis => s.mount.hysteresis_steps = whole("the hysteresis")?,
            Self::FringeDrift => s.michelson.fringe_drift_rad = value,
        }
        s.validate()
            .map_err(|e| fail(crate::console::one_line(&e)))?;
        Ok(s)
    }
}

/// What a knob scales a scene's realism by: its beam's size and brightness, the image size.
#[derive(Clone, Copy)]
struct SceneScale {
    radius_px: f64,
    peak: f64,
    size: [f64; 2],
}

/// Calls `f` on the realism table of every scene with that scene's scale.
fn each_scene(s: &mut ScenarioFile, f: impl Fn(&mut RealismParams, SceneScale)) {
    let m = &mut s.michelson;
    let scale = SceneScale {
        radius_px: m.beam_radius_px[0],
        peak: m.beam_peak_level[0],
        size: [f64::from(m.width_px), f64::from(m.height_px)],
    };
    f(&mut m.realism, scale);
    let c = &mut s.cavity;
    let scale = SceneScale {
        radius_px: c.secondary.radius_px,
        peak: c.secondary.peak_level,
        size: [f64::from(c.width_px), f64::from(c.height_px)],
    };
    f(&mut c.realism, scale);
    let r = &mut s.relay;
    let scale = SceneScale {
        radius_px: r.beam_radius_mm * f64::from(r.camera.width_px) / r.camera.sensor_width_mm,
        peak: r.spot_peak_level,
        size: [f64::from(r.camera.width_px), f64::from(r.camera.height_px)],
    };
    f(&mut r.realism, scale);
}

impl std::fmt::Display for Knob {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One point of a sweep.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setting {
    pub knob: Knob,
    pub value: f64,
}

impl std::fmt::Display for Setting {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}={}", self.knob, self.knob.format_value(self.value))
    }
}

/// A parsed `--sweep KNOB=v1,v2,...` (or `--sweep KNOB` for the knob's standard values).
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSpec {
    pub knob: Knob,
    pub values: Vec<f64>,
}

impl SweepSpec {
    /// Parses one `--sweep`: `KNOB=v1,v2,...`, `KNOB` (its standard values), or `all`
    /// (every knob at its standard values).
    pub fn parse_many(text: &str) -> Result<Vec<Self>, String> {
        if text.trim() == "all" {
            return Ok(Knob::ALL
                .into_iter()
                .map(|knob| Self {
                    knob,
                    values: knob.standard_values().to_vec(),
                })
                .collect());
        }
        Self::parse(text).map(|spec| vec![spec])
    }

    pub fn parse(text: &str) -> Result<Self, String> {
        let Some((name, values)) = text.split_once('=') else {
            let knob = Knob::parse(text).map_err(|e| {
                format!("{e}; write KNOB=v1,v2,... (for example noise=0,5,10), KNOB or all")
            })?;
            return Ok(Self {
                knob,
                values: knob.standard_values().to_vec(),
            });
        };
        let knob = Knob::parse(name)?;
        let values = values
            .split(',')
            .filter(|v| !v.trim().is_empty())
            .map(|v| knob.parse_value(v))
            .collect::<Result<Vec<f64>, String>>()?;
        if values.is_empty() {
            return Err(format!(
                "sweep knob {knob}: give at least one value, as {knob}=v1,v2,..."
            ));
        }
        Ok(Self { knob, values })
    }

    /// The scenario of every value, validated up front so a bad value fails before any run.
    pub fn scenarios(&self, base: &ScenarioFile) -> Result<Vec<(Setting, ScenarioFile)>, String> {
        self.values
            .iter()
            .map(|&value| {
                let setting = Setting {
                    knob: self.knob,
                    value,
                };
                self.knob.apply(base, value).map(|s| (setting, s))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweeps_parse_and_bad_input_names_the_knob() {
        let spec = SweepSpec::parse("noise=0, 2.5,10").unwrap();
        assert_eq!(spec.knob, Knob::Noise);
        assert_eq!(spec.values, vec![0.0, 2.5, 10.0]);
        assert_eq!(
            SweepSpec::parse("offset-scale=1").unwrap().knob,
            Knob::OffsetScale
        );
        let unknown = SweepSpec::parse("glare=1,2").unwrap_err();
        assert!(
            unknown.contains("\"glare\"") && unknown.contains("cross_coupling"),
            "{unknown}"
        );
        let not_number = SweepSpec::parse("backlash=10,lots").unwrap_err();
        assert!(
            not_number.contains("backlash") && not_number.contains("\"lots\""),
            "{not_number}"
        );
        assert!(SweepSpec::parse("noise=").unwrap_err().contains("noise"));
        assert_eq!(
            SweepSpec::parse("noise").unwrap().values,
            Knob::Noise.standard_values()
        );
        assert!(SweepSpec::parse("glare").unwrap_err().contains("KNOB="));
        let profiles = SweepSpec::parse("beam_profile=gaussian,tem01").unwrap();
        assert_eq!(profiles.values, vec![0.0, 2.0]);
        assert!(
            SweepSpec::parse("beam_profile=square")
                .unwrap_err()
                .contains("tem01")
        );
        assert_eq!(SweepSpec::parse_many("all").unwrap().len(), Knob::ALL.len());
    }

    #[test]
    fn knobs_set_their_fields_and_leave_the_rest() {
        let base = ScenarioFile::default();
        let noisy = Knob::Noise.apply(&base, 12.0).unwrap();
        assert_eq!(
            [
                noisy.michelson.noise.std,
                noisy.cavity.noise.std,
                noisy.relay.noise.std
            ],
            [12.0; 3]
        );
        let loose = Knob::Backlash.apply(&base, 200.0).unwrap();
        assert_eq!(loose.mount.backlash_steps, 200);
        assert_eq!(
            loose.mount.compensation_steps,
            base.mount.compensation_steps
        );
        let far = Knob::OffsetScale.apply(&base, 0.5).unwrap();
        assert_eq!(far.michelson.horizontal_offset_range_steps, 3072);
        assert_eq!(far.relay.offset_range_steps, 5000);
        let bright = Knob::ArtefactBrightness.apply(&base, 2.0).unwrap();
        assert_eq!(bright.cavity.ring.level, 2.0 * base.cavity.ring.level);
        assert_eq!(
            bright.cavity.ghosts[1].peak_level,
            2.0 * base.cavity.ghosts[1].peak_level
        );
        let shaky = Knob::PlacementError.apply(&base, 3.0).unwrap();
        assert!((shaky.relay.camera.placement_position_std_mm - 0.3).abs() < 1e-12);
        let coupled = Knob::CrossCoupling.apply(&base, 0.5).unwrap();
        let m = coupled.michelson.mirror_1_sensitivity_px_per_step;
        assert!(
            (m[0][1] - 0.085).abs() < 1e-12 && (m[1][0] + 0.08).abs() < 1e-12,
            "{m:?}"
        );
        assert_eq!(
            m[0][0],
            base.michelson.mirror_1_sensitivity_px_per_step[0][0]
        );
        let fast = Knob::SensitivityScale.apply(&base, 2.0).unwrap();
        assert_eq!(
            fast.relay.tilt_rad_per_step,
            2.0 * base.relay.tilt_rad_per_step
        );
        assert_eq!(fast.mount, base.mount);
    }

    #[test]
    fn every_knob_takes_its_standard_and_harsh_values() {
        let base = ScenarioFile::default();
        for knob in Knob::ALL {
            let values = knob.standard_values();
            for &value in values.iter().chain(knob.harsh_values()) {
                let scenario = knob.apply(&base, value).unwrap_or_else(|e| panic!("{e}"));
                // The first standard value is the default scene (cross-coupling's default
                // is the scenes' own mild coupling, not 0).
                let default = value == values[0] && knob != Knob::CrossCoupling;
                assert_eq!(scenario == base, default, "{knob}={value}");
            }
        }
    }

    #[test]
    fn realism_knobs_scale_with_each_scene() {
        let base = ScenarioFile::default();
        let stray = Knob::StraySpots.apply(&base, 3.0).unwrap();
        assert_eq!(stray.michelson.realism.stray_spots.len(), 3);
        assert_eq!(
            stray.michelson.realism.stray_spots[0].radius_px,
            0.8 * 130.0
        );
        assert_eq!(stray.cavity.realism.stray_spots[1].peak_level, 0.8 * 40.0);
        let relay_spot = &stray.relay.realism.stray_spots[2];
        assert!((relay_spot.radius_px - 80.0).abs() < 1e-9, "{relay_spot:?}");
        assert!((relay_spot.centre_offset_px[1] - 0.36 * 480.0).abs() < 1e-9);
        let lobes = Knob::BeamProfile.apply(&base, 2.0).unwrap();
        assert!(matches!(
            lobes.relay.realism.beam_profile,
            BeamProfile::HermiteGauss { m: 0, n: 1, .. }
        ));
        let etalon = Knob::Texture.apply(&base, 0.6).unwrap();
        assert!(matches!(
            etalon.michelson.realism.texture,
            Texture::Etalon { contrast, period_px, .. } if contrast == 0.6 && (period_px - 45.5).abs() < 1e-9
        ));
        let turned = Knob::CameraRotation.apply(&base, 90.0).unwrap();
        assert_eq!(turned.cavity.realism.camera_rotation_deg, 90.0);
        assert!(
            Knob::CameraFlip
                .apply(&base, 0.5)
                .unwrap_err()
                .contains("camera_flip=0.5")
        );
        assert!(
            Knob::StraySpots
                .apply(&base, 7.0)
                .unwrap_err()
                .contains("at most 6")
        );
        assert!(Knob::FringeDrift.applies_to(TaskKind::Michelson));
        assert!(!Knob::FringeDrift.applies_to(TaskKind::Relay));
    }

    #[test]
    fn invalid_values_name_the_knob_and_the_field() {
        let base = ScenarioFile::default();
        let error = Knob::Noise.apply(&base, 500.0).unwrap_err();
        assert!(
            error.contains("noise=500") && error.contains("noise.std"),
            "{error}"
        );
        let error = Knob::Backlash.apply(&base, 2.5).unwrap_err();
        assert!(
            error.contains("backlash=2.5") && error.contains("whole"),
            "{error}"
        );
        let error = Knob::CrossCoupling.apply(&base, 1.0).unwrap_err();
        assert!(
            error.contains("cross_coupling=1") && error.contains("invertible"),
            "{error}"
        );
        let spec = SweepSpec::parse("sensitivity_scale=1,0").unwrap();
        let error = spec.scenarios(&base).unwrap_err();
        assert!(error.contains("sensitivity_scale=0"), "{error}");
    }
}
