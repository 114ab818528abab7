//! Difficulty sweeps: one scenario knob varied over a list of values, to find where each
//! method breaks. Every knob maps onto scenario fields; a value that makes the scenario
//! invalid is an error naming the knob, the value and the field.

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
}

impl Knob {
    pub const ALL: [Knob; 7] = [
        Knob::Noise,
        Knob::Backlash,
        Knob::OffsetScale,
        Knob::ArtefactBrightness,
        Knob::PlacementError,
        Knob::SensitivityScale,
        Knob::CrossCoupling,
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
        }
    }

    /// Whether the knob changes anything in `task`'s scene or mechanics.
    pub fn applies_to(self, task: TaskKind) -> bool {
        match self {
            Self::Noise | Self::Backlash | Self::OffsetScale | Self::SensitivityScale => true,
            Self::ArtefactBrightness => task == TaskKind::Cavity,
            Self::PlacementError => task == TaskKind::Relay,
            Self::CrossCoupling => task != TaskKind::Relay,
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

    /// The scenario with this knob set to `value`, validated.
    pub fn apply(self, base: &ScenarioFile, value: f64) -> Result<ScenarioFile, String> {
        let fail = |reason: String| format!("sweep knob {}={value}: {reason}", self.name());
        if !value.is_finite() {
            return Err(fail("the value must be a finite number".into()));
        }
        let mut s = base.clone();
        match self {
            Self::Noise => {
                s.michelson.noise.std = value;
                s.cavity.noise.std = value;
                s.relay.noise.std = value;
            }
            Self::Backlash => {
                if value < 0.0 || value.fract() != 0.0 || value > f64::from(u32::MAX) {
                    return Err(fail("backlash must be a whole number of steps >= 0".into()));
                }
                s.mount.backlash_steps = value as u32;
            }
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
        }
        s.validate().map_err(|e| fail(crate::cli::one_line(&e)))?;
        Ok(s)
    }
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

/// A parsed `--sweep KNOB=v1,v2,...`.
#[derive(Clone, Debug, PartialEq)]
pub struct SweepSpec {
    pub knob: Knob,
    pub values: Vec<f64>,
}

impl SweepSpec {
    pub fn parse(text: &str) -> Result<Self, String> {
        let (name, values) = text.split_once('=').ok_or_else(|| {
            format!("sweep {text:?}: write KNOB=v1,v2,... (for example noise=0,5,10)")
        })?;
        let knob = Knob::parse(name)?;
        let values = values
            .split(',')
            .filter(|v| !v.trim().is_empty())
            .map(|v| {
                v.trim()
                    .parse::<f64>()
                    .ok()
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| format!("sweep knob {knob}: {:?} is not a number", v.trim()))
            })
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
        assert!(SweepSpec::parse("noise").unwrap_err().contains("KNOB="));
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
