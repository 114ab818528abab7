//! Scenario files: everything a simulated run depends on, in one TOML file with documented
//! defaults. `[michelson]`, `[cavity]` and `[relay]` configure the scenes (see
//! `optalign-optics`), `[mount]` the simulated mechanics and the firmware's compensation,
//! `[timing]` the modelled wall-clock, `[tasks.*]` bounds and budgets.

use std::path::Path;

use anyhow::Context;
use optalign_optics::{
    Scenario as SceneParams,
    scenario::{CavityParams, MichelsonParams, RelayParams},
};
use optalign_protocol::BacklashMode;
use serde::{Deserialize, Serialize};

use crate::task::{BenchGeometry, TaskKind, TaskLimits};

/// The simulated mounts and how the firmware is configured for them (`[mount]`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MountParams {
    /// True gear/screw dead band of every axis, steps. Default 30 (a 28BYJ-48 gearbox).
    pub backlash_steps: u32,
    /// Backlash the firmware compensates, steps. Default 30 (calibrated to the true value).
    pub compensation_steps: u16,
    /// Compensation mode: "off", "one_sided" or "take_up". Default "one_sided".
    pub compensation_mode: CompensationMode,
    /// Probability that the mount loses any one step. Default 0.
    pub lost_step_probability: f64,
    /// Cruise speed, steps/s. Default 800.
    pub max_speed: u32,
    /// Acceleration, steps/s². Default 2000.
    pub acceleration: u32,
    /// Amplitude of each screw's periodic pitch error, steps: the mirror moves that much
    /// more or less than the screw over a period. Default 0.
    pub pitch_error_steps: u32,
    /// Period of the pitch error, steps. Default 4096 (one revolution).
    pub pitch_period_steps: u32,
    /// Elastic hysteresis beyond the dead band, steps either side: after a reversal the
    /// mirror lags the screw by up to twice this, taken up gradually over a few times it
    /// (not compensated by the firmware, which knows only the dead band). Default 0.
    pub hysteresis_steps: u32,
}

impl Default for MountParams {
    fn default() -> Self {
        Self {
            backlash_steps: 30,
            compensation_steps: 30,
            compensation_mode: CompensationMode::OneSided,
            lost_step_probability: 0.0,
            max_speed: 800,
            acceleration: 2000,
            pitch_error_steps: 0,
            pitch_period_steps: 4096,
            hysteresis_steps: 0,
        }
    }
}

/// Backlash compensation mode, as spelt in scenario files.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CompensationMode {
    Off,
    OneSided,
    TakeUp,
}

impl From<CompensationMode> for BacklashMode {
    fn from(mode: CompensationMode) -> Self {
        match mode {
            CompensationMode::Off => BacklashMode::Off,
            CompensationMode::OneSided => BacklashMode::OneSided,
            CompensationMode::TakeUp => BacklashMode::TakeUp,
        }
    }
}

/// The modelled wall-clock time of a run (`[timing]`), for speed-vs-accuracy charts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TimingParams {
    /// Camera settling time after a motor move, s. Default 0.5.
    pub settle_after_move_s: f64,
    /// Time the robot arm takes to move the camera to another station, s. Default 8.
    pub camera_move_s: f64,
    /// Time to grab one frame, s. Default 0.1.
    pub frame_s: f64,
}

impl Default for TimingParams {
    fn default() -> Self {
        Self {
            settle_after_move_s: 0.5,
            camera_move_s: 8.0,
            frame_s: 0.1,
        }
    }
}

/// A whole scenario file.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScenarioFile {
    pub michelson: MichelsonParams,
    pub cavity: CavityParams,
    pub relay: RelayParams,
    pub mount: MountParams,
    pub timing: TimingParams,
    pub tasks: TaskLimits,
}

impl ScenarioFile {
    /// Reads and validates a scenario file, photo paths taken from its folder; errors name
    /// the file, the field and the reason.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read scenario {}", path.display()))?;
        let folder = path.parent().unwrap_or(Path::new("."));
        Self::parse_in(&text, folder)
            .with_context(|| format!("invalid scenario {}", path.display()))
    }

    /// Loads `path`, or the defaults when none is given.
    pub fn load_or_default(path: Option<&Path>) -> anyhow::Result<Self> {
        path.map_or_else(|| Ok(Self::default()), Self::load)
    }

    /// Parses and validates a scenario, photo paths taken from the working folder.
    pub fn parse(text: &str) -> anyhow::Result<Self> {
        Self::parse_in(text, Path::new(""))
    }

    /// Parses a scenario, takes relative photo paths from `folder`, and validates it.
    fn parse_in(text: &str, folder: &Path) -> anyhow::Result<Self> {
        let mut scenario: Self =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{}", e.to_string().trim()))?;
        scenario.michelson.realism.resolve_paths(folder);
        scenario.cavity.realism.resolve_paths(folder);
        scenario.relay.realism.resolve_paths(folder);
        scenario.validate()?;
        Ok(scenario)
    }

    pub fn validate(&self) -> anyhow::Result<()> {
        self.scenes().validate()?;
        self.tasks.validate().map_err(anyhow::Error::msg)?;
        let mount = &self.mount;
        anyhow::ensure!(
            (0.0..=1.0).contains(&mount.lost_step_probability),
            "mount.lost_step_probability: must be within 0..=1, got {}",
            mount.lost_step_probability
        );
        anyhow::ensure!(mount.max_speed > 0, "mount.max_speed: must be > 0 steps/s");
        anyhow::ensure!(
            mount.acceleration > 0,
            "mount.acceleration: must be > 0 steps/s²"
        );
        for (name, value) in [
            ("mount.backlash_steps", mount.backlash_steps),
            ("mount.pitch_error_steps", mount.pitch_error_steps),
            ("mount.hysteresis_steps", mount.hysteresis_steps),
        ] {
            anyhow::ensure!(value <= 2000, "{name}: must be <= 2000, got {value}");
        }
        anyhow::ensure!(
            mount.pitch_period_steps > 0,
            "mount.pitch_period_steps: must be > 0 steps"
        );
        let timing = &self.timing;
        for (name, value) in [
            ("timing.settle_after_move_s", timing.settle_after_move_s),
            ("timing.camera_move_s", timing.camera_move_s),
            ("timing.frame_s", timing.frame_s),
        ] {
            anyhow::ensure!(
                value.is_finite() && value >= 0.0,
                "{name}: must be a time >= 0 s, got {value}"
            );
        }
        Ok(())
    }

    /// The geometry of `task`'s simulated bench, for the policies' brief: the image size,
    /// and for the relay its sensor, the mount's nominal tilt per step, the mirrors and the
    /// stations.
    pub fn geometry(&self, task: TaskKind) -> BenchGeometry {
        match task {
            TaskKind::Michelson => BenchGeometry {
                image_px: Some([self.michelson.width_px, self.michelson.height_px]),
                ..BenchGeometry::default()
            },
            TaskKind::Cavity => BenchGeometry {
                image_px: Some([self.cavity.width_px, self.cavity.height_px]),
                ..BenchGeometry::default()
            },
            TaskKind::Relay => {
                let r = &self.relay;
                BenchGeometry {
                    sensor_mm: Some([r.camera.sensor_width_mm, r.camera.sensor_height_mm]),
                    image_px: Some([r.camera.width_px, r.camera.height_px]),
                    tilt_rad_per_step: Some(r.tilt_rad_per_step),
                    relay_sides_mm: Some([r.long_side_mm, r.short_side_mm]),
                    mirror_diameter_mm: Some(r.mirror_diameter_mm),
                    station_distances_mm: Some(r.station_distances_mm),
                    placement_repeatability_mm: Some(r.camera.placement_position_std_mm)
                        .filter(|spread| *spread > 0.0),
                }
            }
        }
    }

    /// The scene tables as the optics crate takes them.
    pub fn scenes(&self) -> SceneParams {
        SceneParams {
            michelson: self.michelson.clone(),
            cavity: self.cavity.clone(),
            relay: self.relay.clone(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_parse_from_an_empty_file() {
        assert_eq!(ScenarioFile::parse("").unwrap(), ScenarioFile::default());
    }

    #[test]
    fn unknown_fields_and_bad_values_are_named() {
        let error = ScenarioFile::parse("[mount]\nbacklash = 3\n")
            .unwrap_err()
            .to_string();
        assert!(error.contains("backlash"), "{error}");
        let error = ScenarioFile::parse("[mount]\nlost_step_probability = 2.0\n")
            .unwrap_err()
            .to_string();
        assert!(error.contains("mount.lost_step_probability"), "{error}");
        let error = ScenarioFile::parse("[tasks.relay]\nbudget = 0\n")
            .unwrap_err()
            .to_string();
        assert!(error.contains("tasks.relay.budget"), "{error}");
        let error = ScenarioFile::parse("[timing]\ncamera_move_s = -1\n")
            .unwrap_err()
            .to_string();
        assert!(error.contains("timing.camera_move_s"), "{error}");
    }

    /// A shipped scenario file, by its name in docs/scenarios.
    fn shipped(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../docs/scenarios")
            .join(name)
    }

    #[test]
    fn photo_scenarios_load_their_photos_from_the_files_folder_and_render_16_bit() {
        // The tests run in host/: the photos' relative paths only resolve from the file's
        // own folder.
        let michelson = ScenarioFile::load(&shipped("photos-michelson.toml")).unwrap();
        let scene = optalign_optics::Michelson::new(michelson.michelson.clone(), [300, -200, 0, 0])
            .unwrap();
        let frame = scene.render(&[0; 4], 0);
        assert_eq!(frame.full_scale(), u16::MAX);
        assert_eq!((frame.width(), frame.height()), (1280, 960));
        let cavity = ScenarioFile::load(&shipped("photos-cavity.toml")).unwrap();
        let scene = optalign_optics::Cavity::new(cavity.cavity.clone(), [0; 2]).unwrap();
        // The background photograph's ambient light (about 50 gray levels) stays put.
        let frame = scene.render(&[0; 2], 0);
        let corner = f64::from(frame.pixel(20, 20)) * f64::from(frame.levels_per_count());
        assert!((35.0..70.0).contains(&corner), "{corner}");
    }

    #[test]
    fn every_shipped_scenario_loads_and_renders_each_task() {
        let folder = shipped("");
        let mut files: Vec<_> = std::fs::read_dir(&folder)
            .unwrap()
            .map(|entry| entry.unwrap().path())
            .filter(|path| path.extension().is_some_and(|e| e == "toml"))
            .collect();
        files.sort();
        assert!(files.len() >= 6, "{files:?}");
        for path in files {
            let file =
                ScenarioFile::load(&path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
            let michelson = optalign_optics::Michelson::new(file.michelson.clone(), [0; 4]);
            let cavity = optalign_optics::Cavity::new(file.cavity.clone(), [0; 2]);
            let (michelson, cavity) = (michelson.unwrap(), cavity.unwrap());
            assert!(
                michelson.render(&[0; 4], 0).width() > 0,
                "{}",
                path.display()
            );
            assert!(cavity.render(&[0; 2], 0).width() > 0, "{}", path.display());
        }
    }

    #[test]
    fn bad_photo_paths_crops_and_files_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let write = |text: &str| {
            let path = dir.path().join("s.toml");
            std::fs::write(&path, text).unwrap();
            ScenarioFile::load(&path).unwrap_err()
        };
        let missing = write(
            "[michelson.realism]\nbeam_profile = { kind = \"image\", path = \"nowhere.png\" }\n",
        );
        let text = format!("{missing:#}");
        assert!(
            text.contains("michelson.realism.beam_profile.path") && text.contains("nowhere.png"),
            "{text}"
        );
        std::fs::write(dir.path().join("junk.png"), b"not an image").unwrap();
        let junk = write("[cavity.realism]\nbackground_photo = { path = \"junk.png\" }\n");
        let text = format!("{junk:#}");
        assert!(
            text.contains("cavity.realism.background_photo") && text.contains("not a usable image"),
            "{text}"
        );
        let photo = shipped("photos/k-500mm.png");
        let outside = write(&format!(
            "[relay.realism]\nbeam_profile = {{ kind = \"image\", path = {photo:?}, crop = [1200, 0, 200, 10] }}\n"
        ));
        let text = format!("{outside:#}");
        assert!(text.contains("does not lie inside"), "{text}");
        let erase = write(&format!(
            "[michelson.realism]\nbackground_photo = {{ path = {photo:?}, erase = [[0, 0, 0, 5]] }}\n"
        ));
        assert!(format!("{erase:#}").contains("does not lie inside"));
    }
}
