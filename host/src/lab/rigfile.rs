//! Rig files: a bench described in TOML — its controllers, which controller axis is which
//! task axis, the camera, the camera mover and its stations, settle times, the task's
//! limits and how the bench is scored. Invalid files are rejected with the field and the
//! reason before anything connects or moves.

use std::collections::{BTreeMap, HashSet};
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use serde::{Deserialize, Serialize};

use crate::bounds;
use crate::link::Endpoint;
use crate::task::{BenchGeometry, TaskKind, TaskLimits, cavity, michelson};

/// A whole rig file.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RigFile {
    /// The task this bench is set up for.
    pub task: TaskKind,
    /// The motor controllers (`[[controller]]` tables).
    #[serde(rename = "controller")]
    pub controllers: Vec<ControllerSpec>,
    /// Task axis name -> controller axis.
    pub axes: BTreeMap<String, AxisSpec>,
    pub camera: CameraSpec,
    /// How the camera moves between stations (relay only).
    #[serde(default)]
    pub mover: Option<MoverSpec>,
    #[serde(default)]
    pub settle: SettleSpec,
    /// Bounds and budgets; defaults are the paper's, a bench may narrow them.
    #[serde(default)]
    pub limits: TaskLimits,
    #[serde(default)]
    pub scoring: ScoringSpec,
    /// What is known of the bench's geometry (every field optional; docs/lab.md): told to
    /// the policies.
    #[serde(default)]
    pub geometry: BenchGeometry,
}

/// One motor controller.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ControllerSpec {
    /// A name the `[axes]` table refers to.
    pub name: String,
    /// `tcp://HOST:PORT` or `serial://PATH`.
    pub url: String,
    /// Environment variable holding the access key. Default `OPTALIGN_KEY`.
    #[serde(default = "default_key_env")]
    pub key_env: String,
}

fn default_key_env() -> String {
    "OPTALIGN_KEY".into()
}

/// Where one task axis lives.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisSpec {
    pub controller: String,
    pub axis: u8,
    /// The task's positive direction is the controller's negative one.
    #[serde(default)]
    pub invert: bool,
}

/// The camera.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum CameraSpec {
    /// A V4L2 device (Linux): fixed exposure and gain.
    V4l2 {
        device: PathBuf,
        /// Absolute exposure in the driver's units (auto exposure is switched off).
        exposure: i64,
        #[serde(default)]
        gain: i64,
        /// Frames thrown away after every move (stale frames in the driver's queue).
        #[serde(default = "default_discard")]
        discard_frames: u32,
        /// Frames averaged per capture.
        #[serde(default = "one")]
        average: u32,
    },
    /// A command that writes one image; `{output}` in the arguments is replaced by the path.
    Command {
        argv: Vec<String>,
        #[serde(default = "default_timeout")]
        timeout_s: f64,
    },
    /// A URL that answers a GET with one image taken when asked (a network camera's
    /// snapshot URL, or the rehearsal bench of `optalign peer --scene`).
    Http {
        url: String,
        #[serde(default = "default_timeout")]
        timeout_s: f64,
    },
    /// The newest image file in a folder, written by the camera's own software.
    Folder {
        path: PathBuf,
        /// How long to wait for a new image after a move.
        #[serde(default = "default_timeout")]
        timeout_s: f64,
    },
    /// The scene renderer on the true shafts of a simulated peer running in this process.
    Sim {
        #[serde(default)]
        seed: u64,
        /// Scenario file with the scene parameters; defaults when omitted.
        #[serde(default)]
        scenario: Option<PathBuf>,
    },
}

fn default_discard() -> u32 {
    2
}

fn one() -> u32 {
    1
}

fn default_timeout() -> f64 {
    30.0
}

/// The camera mover (relay).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum MoverSpec {
    /// Runs a command per move; `{station}` in the arguments becomes C1..C8.
    Command {
        argv: Vec<String>,
        #[serde(default = "default_mover_timeout")]
        timeout_s: f64,
    },
    /// POSTs `{"station": "C3"}` to a URL and waits for a 2xx answer.
    Http {
        url: String,
        #[serde(default = "default_mover_timeout")]
        timeout_s: f64,
    },
    /// Asks a person to place the camera and press Enter.
    Manual,
    /// Moves the simulated camera (with its placement error).
    Sim,
}

fn default_mover_timeout() -> f64 {
    120.0
}

/// Settle times.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SettleSpec {
    /// After a motor move, before the image, s. Default 0.5.
    pub after_motor_s: f64,
    /// After a camera move, s. Default 2.
    pub after_camera_s: f64,
}

impl Default for SettleSpec {
    fn default() -> Self {
        Self {
            after_motor_s: 0.5,
            after_camera_s: 2.0,
        }
    }
}

/// How a bench run is scored without hidden truth.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScoringSpec {
    /// Michelson: the response calibration (`optalign calibrate response` output).
    pub michelson_calibration: Option<PathBuf>,
    /// Cavity: controller positions (x, y) of the aligned reference, recorded by hand.
    pub cavity_aligned: Option<[i32; 2]>,
}

/// The task axis names a rig file maps, in task axis order.
pub fn task_axis_names(task: TaskKind) -> Vec<String> {
    match task {
        TaskKind::Michelson => michelson::AXIS_NAMES
            .iter()
            .map(|s| s.to_string())
            .collect(),
        TaskKind::Cavity => cavity::AXIS_NAMES.iter().map(|s| s.to_string()).collect(),
        TaskKind::Relay => (1..=4)
            .flat_map(|m| [format!("m{m}v"), format!("m{m}h")])
            .collect(),
    }
}

/// A task axis resolved to its controller.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct AxisRoute {
    pub controller: usize,
    pub axis: u8,
    pub sign: i32,
}

impl RigFile {
    /// Reads and validates a rig file.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read rig file {}", path.display()))?;
        let base = path.parent().unwrap_or(Path::new("."));
        Self::parse(&text, base).with_context(|| format!("invalid rig file {}", path.display()))
    }

    /// Parses and validates; relative paths in the file are resolved against `base`.
    pub fn parse(text: &str, base: &Path) -> anyhow::Result<Self> {
        let mut rig: Self =
            toml::from_str(text).map_err(|e| anyhow::anyhow!("{}", e.to_string().trim()))?;
        rig.validate()?;
        rig.resolve_paths(base);
        Ok(rig)
    }

    fn resolve_paths(&mut self, base: &Path) {
        let resolve = |path: &mut PathBuf| {
            if path.is_relative() {
                *path = base.join(&*path);
            }
        };
        match &mut self.camera {
            CameraSpec::Folder { path, .. } => resolve(path),
            CameraSpec::Sim {
                scenario: Some(path),
                ..
            } => resolve(path),
            _ => {}
        }
        if let Some(path) = &mut self.scoring.michelson_calibration {
            resolve(path);
        }
    }

    fn validate(&self) -> anyhow::Result<()> {
        if self.controllers.is_empty() {
            bail!("controller: at least one [[controller]] table is needed");
        }
        let mut names = HashSet::new();
        for (i, controller) in self.controllers.iter().enumerate() {
            if !names.insert(controller.name.as_str()) {
                bail!("controller[{i}].name: {:?} is used twice", controller.name);
            }
            controller
                .url
                .parse::<Endpoint>()
                .with_context(|| format!("controller[{i}].url"))?;
        }
        let expected = task_axis_names(self.task);
        for name in self.axes.keys() {
            if !expected.contains(name) {
                bail!(
                    "axes.{name}: not an axis of the {} task (its axes: {})",
                    self.task,
                    expected.join(", ")
                );
            }
        }
        let mut used = HashSet::new();
        for name in &expected {
            let spec = self.axes.get(name).with_context(|| {
                format!(
                    "axes.{name}: missing; the {} task needs {}",
                    self.task,
                    expected.join(", ")
                )
            })?;
            if !names.contains(spec.controller.as_str()) {
                bail!(
                    "axes.{name}.controller: {:?} is not a [[controller]] name",
                    spec.controller
                );
            }
            if usize::from(spec.axis) >= optalign_protocol::MAX_AXES {
                bail!(
                    "axes.{name}.axis: {} is beyond the protocol's {} axes",
                    spec.axis,
                    optalign_protocol::MAX_AXES
                );
            }
            if !used.insert((spec.controller.as_str(), spec.axis)) {
                bail!(
                    "axes.{name}: controller {:?} axis {} is already mapped to another task axis",
                    spec.controller,
                    spec.axis
                );
            }
        }
        match (&self.mover, self.task) {
            (None, TaskKind::Relay) => {
                bail!("mover: the relay task needs a [mover] to move the camera between stations")
            }
            (Some(_), TaskKind::Michelson | TaskKind::Cavity) => {
                bail!("mover: only the relay task moves the camera; remove [mover]")
            }
            _ => {}
        }
        match &self.camera {
            CameraSpec::V4l2 {
                average, exposure, ..
            } => {
                if *average == 0 {
                    bail!("camera.average: must be at least 1");
                }
                if *exposure <= 0 {
                    bail!(
                        "camera.exposure: must be > 0 (auto exposure is off so brightness means something)"
                    );
                }
            }
            CameraSpec::Command { argv, timeout_s } => {
                if argv.is_empty() {
                    bail!("camera.argv: needs the command to run");
                }
                if !argv.iter().any(|a| a.contains("{output}")) {
                    bail!(
                        "camera.argv: must contain {{output}}, the path the command writes its image to"
                    );
                }
                check_timeout("camera.timeout_s", *timeout_s)?;
            }
            CameraSpec::Http { url, timeout_s } => {
                check_http_url("camera.url", url)?;
                check_timeout("camera.timeout_s", *timeout_s)?;
            }
            CameraSpec::Folder { timeout_s, .. } => check_timeout("camera.timeout_s", *timeout_s)?,
            CameraSpec::Sim { .. } => {}
        }
        match &self.mover {
            Some(MoverSpec::Command { argv, timeout_s }) => {
                if !argv.iter().any(|a| a.contains("{station}")) {
                    bail!("mover.argv: must contain {{station}}, replaced by C1..C8");
                }
                check_timeout("mover.timeout_s", *timeout_s)?;
            }
            Some(MoverSpec::Http { url, timeout_s }) => {
                check_http_url("mover.url", url)?;
                check_timeout("mover.timeout_s", *timeout_s)?;
            }
            _ => {}
        }
        for (name, value) in [
            ("settle.after_motor_s", self.settle.after_motor_s),
            ("settle.after_camera_s", self.settle.after_camera_s),
        ] {
            bounds::seconds(name, value, true).map_err(anyhow::Error::msg)?;
        }
        self.limits.validate().map_err(anyhow::Error::msg)?;
        self.geometry
            .validate("geometry")
            .map_err(anyhow::Error::msg)?;
        Ok(())
    }

    /// Each task axis, in task order, resolved to (controller index, axis, sign).
    pub fn routes(&self) -> Vec<AxisRoute> {
        task_axis_names(self.task)
            .iter()
            .map(|name| {
                let spec = &self.axes[name];
                AxisRoute {
                    controller: self
                        .controllers
                        .iter()
                        .position(|c| c.name == spec.controller)
                        .expect("validated: every axis names a controller"),
                    axis: spec.axis,
                    sign: if spec.invert { -1 } else { 1 },
                }
            })
            .collect()
    }
}

fn check_http_url(field: &str, url: &str) -> anyhow::Result<()> {
    if !(url.starts_with("http://") || url.starts_with("https://")) {
        bail!("{field}: must be an http:// or https:// URL, got {url:?}");
    }
    Ok(())
}

fn check_timeout(field: &str, value: f64) -> anyhow::Result<()> {
    bounds::seconds(field, value, false)
        .map(drop)
        .map_err(anyhow::Error::msg)
}
