//! Response calibrations: the linear map from motor positions to the image position of a
//! beam, as measured by `optalign calibrate response` and used to score Michelson runs on a
//! bench (the paper scores from commanded positions through this calibration).

use std::path::Path;

use anyhow::Context;
use serde::{Deserialize, Serialize};

use super::calibrate::fit::apply_affine;
use super::rigfile::RigFile;

/// The file name of a bench's response calibration when the rig file names none.
pub const DEFAULT_CALIBRATION_FILE: &str = "response-calibration.json";

/// Where the response calibration of the bench described by `rig` (read from `rig_path`)
/// is: the file `scoring.michelson_calibration` names, else
/// [`DEFAULT_CALIBRATION_FILE`] beside the rig file.
pub fn default_calibration_path(rig_path: &Path, rig: &RigFile) -> std::path::PathBuf {
    rig.scoring
        .michelson_calibration
        .clone()
        .unwrap_or_else(|| {
            rig_path
                .parent()
                .unwrap_or(Path::new("."))
                .join(DEFAULT_CALIBRATION_FILE)
        })
}

/// One mirror's fitted response: `centre + matrix · (position - reference)`, where
/// positions are task-axis coordinates (controller steps, with the rig's inversion applied).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MirrorResponse {
    /// 1-based mirror number.
    pub mirror: usize,
    /// Task axis names of the mirror's two axes.
    pub axes: [String; 2],
    /// Task axis indices of those axes.
    pub axis_indices: [usize; 2],
    /// Positions of the two axes at the reference point.
    pub reference_steps: [f64; 2],
    /// Fitted beam centre at the reference point, px.
    pub centre_px: [f64; 2],
    /// px per step: `[[dx/da1, dx/da2], [dy/da1, dy/da2]]`.
    pub matrix_px_per_step: [[f64; 2]; 2],
    /// Root-mean-square residual of the fit, px.
    pub residual_rms_px: f64,
    /// Number of images the fit used.
    pub points: usize,
    /// Where the brightest beam that stayed put during the scan was (the cavity's primary),
    /// px: what the mirror's beam is measured from when the camera may have shifted.
    #[serde(default)]
    pub stationary_px: Option<[f64; 2]>,
}

impl MirrorResponse {
    /// Predicted beam centre at task-axis positions `positions`, px.
    pub fn predict(&self, positions: &[f64]) -> [f64; 2] {
        let steps = [
            positions[self.axis_indices[0]],
            positions[self.axis_indices[1]],
        ];
        apply_affine(
            self.centre_px,
            &self.matrix_px_per_step,
            self.reference_steps,
            steps,
        )
    }
}

/// A calibration file: one entry per calibrated mirror, and the image size.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ResponseCalibration {
    pub image_size_px: [u32; 2],
    pub mirrors: Vec<MirrorResponse>,
}

impl ResponseCalibration {
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read calibration {}", path.display()))?;
        serde_json::from_str(&text)
            .with_context(|| format!("{} is not a response calibration", path.display()))
    }

    /// Loads `path` if it exists, or starts an empty calibration.
    pub fn load_or_new(path: &Path) -> anyhow::Result<Self> {
        if path.exists() {
            Self::load(path)
        } else {
            Ok(Self::default())
        }
    }

    pub fn save(&self, path: &Path) -> anyhow::Result<()> {
        std::fs::write(path, serde_json::to_vec_pretty(self)?)
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// Replaces (or adds) one mirror's entry.
    pub fn set(&mut self, response: MirrorResponse) {
        self.mirrors.retain(|m| m.mirror != response.mirror);
        self.mirrors.push(response);
        self.mirrors.sort_by_key(|m| m.mirror);
    }

    pub fn mirror(&self, mirror: usize) -> Option<&MirrorResponse> {
        self.mirrors.iter().find(|m| m.mirror == mirror)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_calibration_is_the_named_file_or_beside_the_rig_file() {
        let text = "task = \"cavity\"\n[[controller]]\nname = \"a\"\nurl = \"tcp://127.0.0.1:1\"\n[axes]\nx = { controller = \"a\", axis = 0 }\ny = { controller = \"a\", axis = 1 }\n[camera]\nkind = \"sim\"\n";
        let rig = RigFile::parse(text, Path::new("benches")).unwrap();
        assert_eq!(
            default_calibration_path(Path::new("benches/a.toml"), &rig),
            Path::new("benches/response-calibration.json")
        );
        let named = format!("{text}[scoring]\nmichelson_calibration = \"m.json\"\n");
        let rig = RigFile::parse(&named, Path::new("benches")).unwrap();
        assert_eq!(
            default_calibration_path(Path::new("elsewhere/a.toml"), &rig),
            Path::new("benches/m.json")
        );
    }

    #[test]
    fn predicts_linearly_from_the_reference() {
        let response = MirrorResponse {
            mirror: 2,
            axes: ["mirror_2_axis_1".into(), "mirror_2_axis_2".into()],
            axis_indices: [2, 3],
            reference_steps: [100.0, -50.0],
            centre_px: [960.0, 540.0],
            matrix_px_per_step: [[0.2, 0.01], [-0.02, 0.15]],
            residual_rms_px: 0.4,
            points: 9,
            stationary_px: None,
        };
        let [x, y] = response.predict(&[0.0, 0.0, 200.0, 50.0]);
        assert!((x - (960.0 + 0.2 * 100.0 + 0.01 * 100.0)).abs() < 1e-9);
        assert!((y - (540.0 - 0.02 * 100.0 + 0.15 * 100.0)).abs() < 1e-9);
        let mut calibration = ResponseCalibration::default();
        calibration.set(response.clone());
        calibration.set(response);
        assert_eq!(calibration.mirrors.len(), 1);
    }
}
