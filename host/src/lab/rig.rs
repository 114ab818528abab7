//! The lab rig: the `Rig` trait on a real bench (or the simulated bench behind the same
//! code path). Motor moves go to the rig file's controllers over the protocol, the camera
//! mover places the camera, the camera takes the image after the settle time.
//!
//! Visible motor settings start at 0: the controllers' positions when the run starts are
//! the origin of the task's commands, as in the paper.

use std::sync::Arc;
use std::time::Duration;

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::{Frame, Station};
use optalign_protocol::{AxisStatus, AxisValue, Command, Faults, MoveOutcome, Status};

use super::camera::{Camera, CommandCamera, FolderCamera, HttpCamera, SimCamera, SimView};
use super::mover::{CameraMover, CommandMover, HttpMover, ManualMover, SimMover};
use super::rehearsal::sim_view;
use super::rigfile::{AxisRoute, CameraSpec, MoverSpec, RigFile};
use super::scoring::LabScorer;
use crate::link::{AccessKey, Client, ClientOptions, Endpoint};
use crate::peer::{SimPeer, registry};
use crate::rig::{ControllerView, Executed, Rig, Score};
use crate::task::relay::{RelayAction, axis_of};
use crate::task::{Action, TaskKind};

/// A bench described by a rig file.
pub struct LabRig {
    rig: RigFile,
    controllers: Vec<Client>,
    routes: Vec<AxisRoute>,
    /// Controller positions of every task axis when the run started.
    origin: Vec<i32>,
    /// Visible (task) settings commanded so far.
    commanded: Vec<i32>,
    camera: Box<dyn Camera>,
    mover: Option<Box<dyn CameraMover>>,
    station: Station,
    scorer: LabScorer,
}

impl LabRig {
    /// Connects every controller, checks the camera works and that the bench can be
    /// scored, before anything moves.
    pub async fn connect(rig: RigFile) -> anyhow::Result<Self> {
        LabScorer::check(&rig)?;
        Self::connect_unscored(rig).await
    }

    /// Like [`connect`](Self::connect) without the scoring check: for calibrating a bench
    /// before it has the calibration it will be scored with.
    pub async fn connect_unscored(rig: RigFile) -> anyhow::Result<Self> {
        let mut controllers = Vec::new();
        for spec in &rig.controllers {
            let endpoint: Endpoint = spec
                .url
                .parse()
                .with_context(|| format!("controller {:?}", spec.name))?;
            let key = std::env::var(&spec.key_env).ok();
            if key.is_none() && !endpoint.is_serial() {
                bail!(
                    "controller {:?} ({endpoint}) needs its access key in the environment variable {} (set key_env in the rig file to use another)",
                    spec.name,
                    spec.key_env
                );
            }
            let options = ClientOptions {
                key: key
                    .as_deref()
                    .map(str::parse::<AccessKey>)
                    .transpose()
                    .with_context(|| format!("reading the access key in {}", spec.key_env))?,
                ..ClientOptions::default()
            };
            let client = Client::connect(endpoint, options).await.with_context(|| {
                format!(
                    "controller {:?} is unreachable; nothing was moved",
                    spec.name
                )
            })?;
            controllers.push(client);
        }
        let routes = rig.routes();
        for (route, name) in routes.iter().zip(super::rigfile::task_axis_names(rig.task)) {
            let axes = controllers[route.controller].identity().axes;
            if route.axis >= axes {
                bail!(
                    "axes.{name}: controller {:?} has axes 0..={}, not {}",
                    rig.controllers[route.controller].name,
                    axes.saturating_sub(1),
                    route.axis
                );
            }
        }
        let origin = read_positions(&controllers, &routes).await?;
        let (mut camera, sim_view) = open_camera(&rig, &controllers, &routes)?;
        let probe = camera.capture().await.with_context(|| {
            format!(
                "the camera ({}) returned no image; nothing was moved",
                camera.describe()
            )
        })?;
        tracing::info!(
            camera = camera.describe(),
            width = probe.width(),
            height = probe.height(),
            "camera ready"
        );
        let mover = open_mover(&rig, sim_view)?;
        let scorer = LabScorer::new(&rig);
        Ok(Self {
            commanded: vec![0; routes.len()],
            controllers,
            routes,
            origin,
            camera,
            mover,
            station: Station::C8,
            scorer,
            rig,
        })
    }

    /// Moves task axes: absolute visible settings, or relative deltas.
    async fn move_axes(&mut self, values: &[(usize, i32)], relative: bool) -> anyhow::Result<f64> {
        let mut per_controller: Vec<Vec<AxisValue>> = vec![Vec::new(); self.controllers.len()];
        for &(task_axis, value) in values {
            let route = &self.routes[task_axis];
            let visible = if relative {
                self.commanded[task_axis] + value
            } else {
                value
            };
            if visible == self.commanded[task_axis] {
                continue;
            }
            let target = self.origin[task_axis] + route.sign * visible;
            per_controller[route.controller].push(AxisValue {
                axis: route.axis,
                steps: target,
            });
            self.commanded[task_axis] = visible;
        }
        let moves = self
            .controllers
            .iter()
            .zip(&per_controller)
            .filter(|(_, targets)| !targets.is_empty())
            .map(|(client, targets)| client.move_to(targets));
        let reports = futures::future::join_all(moves).await;
        let mut seconds: f64 = 0.0;
        for report in reports {
            let report = report?;
            if report.outcome != MoveOutcome::Completed {
                bail!(
                    "a motor move ended early ({:?}); check the mount and the controller",
                    report.outcome
                );
            }
            seconds = seconds.max(f64::from(report.duration_ms) / 1000.0);
        }
        if seconds > 0.0 {
            tokio::time::sleep(Duration::from_secs_f64(self.rig.settle.after_motor_s)).await;
        }
        Ok(seconds)
    }

    /// Moves task axes to absolute visible settings.
    pub async fn move_to(&mut self, values: &[(usize, i32)]) -> anyhow::Result<f64> {
        self.move_axes(values, false).await
    }

    /// Visible settings commanded so far (0 at the start of the run).
    pub fn commanded(&self) -> &[i32] {
        &self.commanded
    }

    /// Task-axis positions: controller positions with the rig's inversion applied.
    pub fn task_positions(&self) -> Vec<f64> {
        self.routes
            .iter()
            .zip(self.origin.iter().zip(&self.commanded))
            .map(|(route, (origin, commanded))| f64::from(route.sign * origin + commanded))
            .collect()
    }

    /// The controller and controller axis behind task axis `axis`.
    pub fn controller_axis(&self, axis: usize) -> (&Client, u8) {
        let route = &self.routes[axis];
        (&self.controllers[route.controller], route.axis)
    }

    /// The sign of task axis `axis` on its controller (-1 when the rig file inverts it).
    pub fn sign(&self, axis: usize) -> i32 {
        self.routes[axis].sign
    }

    /// The rig file the bench was connected from.
    pub fn rig_file(&self) -> &RigFile {
        &self.rig
    }

    /// The state of every task axis on its controller now, in task order (positions as the
    /// controller counts them, without the rig's inversion).
    pub async fn axis_states(&self) -> anyhow::Result<Vec<AxisStatus>> {
        let statuses = statuses(&self.controllers).await?;
        Ok(self
            .routes
            .iter()
            .map(|route| statuses[route.controller].axes[usize::from(route.axis)])
            .collect())
    }

    /// Task axes whose controller reports the position lost (`POSITION_LOST`).
    pub async fn lost_axes(&self) -> anyhow::Result<Vec<usize>> {
        Ok((0..)
            .zip(self.axis_states().await?)
            .filter(|(_, state)| state.faults.has(Faults::POSITION_LOST))
            .map(|(axis, _)| axis)
            .collect())
    }

    /// The controllers' position counters of every task axis now, in task steps (with the
    /// rig's inversion); a lost axis's counter is not where it is.
    pub async fn counters(&self) -> anyhow::Result<Vec<i32>> {
        Ok(self
            .routes
            .iter()
            .zip(self.axis_states().await?)
            .map(|(route, state)| route.sign * state.position)
            .collect())
    }

    /// Asks every controller to decelerate whatever moves, and says which did not answer.
    pub async fn stop_all(&self) -> anyhow::Result<()> {
        let stops = self
            .controllers
            .iter()
            .map(|client| client.command_ok(Command::Stop));
        reached_all(
            futures::future::join_all(stops).await,
            &self.rig.controllers,
            "the stop",
        )
    }

    /// Moves task axes by relative amounts (task steps) in the controllers' recovery mode,
    /// which also moves axes whose position is lost; waits the settle time. The visible
    /// settings are not changed: call [`Self::restart_origin`] once positions are known.
    pub async fn recovery_move(&mut self, deltas: &[(usize, i32)]) -> anyhow::Result<()> {
        let mut per_controller: Vec<Vec<AxisValue>> = vec![Vec::new(); self.controllers.len()];
        for &(task_axis, delta) in deltas {
            let route = &self.routes[task_axis];
            per_controller[route.controller].push(AxisValue {
                axis: route.axis,
                steps: route.sign * delta,
            });
        }
        let moves = self
            .controllers
            .iter()
            .zip(&per_controller)
            .filter(|(_, deltas)| !deltas.is_empty())
            .map(|(client, deltas)| client.recovery_move_by(deltas));
        for report in futures::future::join_all(moves).await {
            let report = report?;
            if report.outcome != MoveOutcome::Completed {
                bail!(
                    "a recovery move ended early ({:?}); check the mount and the controller",
                    report.outcome
                );
            }
        }
        tokio::time::sleep(Duration::from_secs_f64(self.rig.settle.after_motor_s)).await;
        Ok(())
    }

    /// Declares that task axis `axis` is at `position` (task steps) on its controller,
    /// clearing a lost position.
    pub async fn declare(&mut self, axis: usize, position: i32) -> anyhow::Result<()> {
        let route = &self.routes[axis];
        let client = &self.controllers[route.controller];
        client
            .command_ok(Command::SetPosition {
                axis: route.axis,
                position: route.sign * position,
            })
            .await
            .with_context(|| {
                format!(
                    "declaring {} at {position} steps",
                    super::rigfile::task_axis_names(self.rig.task)[axis]
                )
            })
    }

    /// Takes the controllers' positions now as the origin of the visible settings (0), as
    /// at a run's start: after positions were re-declared.
    pub async fn restart_origin(&mut self) -> anyhow::Result<()> {
        self.origin = read_positions(&self.controllers, &self.routes).await?;
        self.commanded = vec![0; self.routes.len()];
        Ok(())
    }

    /// Takes an image now (no settling).
    pub async fn capture(&mut self) -> anyhow::Result<Frame> {
        let frame = self
            .camera
            .capture()
            .await
            .with_context(|| format!("the camera ({}) failed", self.camera.describe()))?;
        self.scorer.observe(self.station, &frame);
        Ok(frame)
    }
}

/// Fails naming every controller that `what` (a command sent to all) did not reach.
fn reached_all(
    results: Vec<Result<(), crate::link::ClientError>>,
    specs: &[super::rigfile::ControllerSpec],
    what: &str,
) -> anyhow::Result<()> {
    let failed: Vec<String> = results
        .into_iter()
        .zip(specs)
        .filter_map(|(result, spec)| result.err().map(|e| format!("{:?}: {e}", spec.name)))
        .collect();
    anyhow::ensure!(
        failed.is_empty(),
        "{what} did not reach every controller: {}",
        failed.join("; ")
    );
    Ok(())
}

async fn statuses(controllers: &[Client]) -> anyhow::Result<Vec<Status>> {
    let mut statuses = Vec::new();
    for client in controllers {
        statuses.push(client.status().await?);
    }
    Ok(statuses)
}

async fn read_positions(controllers: &[Client], routes: &[AxisRoute]) -> anyhow::Result<Vec<i32>> {
    let statuses = statuses(controllers).await?;
    Ok(routes
        .iter()
        .map(|route| statuses[route.controller].axes[usize::from(route.axis)].position)
        .collect())
}

/// The simulated peers behind every controller URL (for the simulated camera).
fn sim_peers(rig: &RigFile, controllers: &[Client]) -> anyhow::Result<Vec<Arc<SimPeer>>> {
    controllers
        .iter()
        .zip(&rig.controllers)
        .map(|(client, spec)| {
            registry::lookup(client.endpoint()).with_context(|| {
                format!(
                    "camera kind \"sim\" needs a simulated peer running in this process behind controller {:?} ({}); to rehearse against `optalign peer` in another process, start it with `--scene TASK --write-rig FILE` and use the rig file it writes (camera kind \"http\")",
                    spec.name, spec.url
                )
            })
        })
        .collect()
}

/// A camera, and the simulated view behind it when it is simulated (for the mover).
type OpenedCamera = (Box<dyn Camera>, Option<Arc<SimView>>);

fn open_camera(
    rig: &RigFile,
    controllers: &[Client],
    routes: &[AxisRoute],
) -> anyhow::Result<OpenedCamera> {
    Ok(match &rig.camera {
        CameraSpec::Command { argv, timeout_s } => (
            Box::new(CommandCamera::new(
                argv.clone(),
                Duration::from_secs_f64(*timeout_s),
            )?),
            None,
        ),
        CameraSpec::Http { url, timeout_s } => (
            Box::new(HttpCamera::new(
                url.clone(),
                Duration::from_secs_f64(*timeout_s),
            )?),
            None,
        ),
        CameraSpec::Folder { path, timeout_s } => (
            Box::new(FolderCamera::new(
                path.clone(),
                Duration::from_secs_f64(*timeout_s),
            )?),
            None,
        ),
        #[cfg(target_os = "linux")]
        CameraSpec::V4l2 {
            device,
            exposure,
            gain,
            discard_frames,
            average,
        } => (
            Box::new(super::camera::V4l2Camera::open(
                device,
                *exposure,
                *gain,
                *discard_frames,
                *average,
            )?),
            None,
        ),
        #[cfg(not(target_os = "linux"))]
        CameraSpec::V4l2 { device, .. } => bail!(
            "camera {}: V4L2 cameras are read on Linux only; use a command, folder or HTTP camera",
            device.display()
        ),
        CameraSpec::Sim { seed, scenario } => {
            let view = sim_view(rig.task, scenario.as_deref(), *seed)?;
            let camera =
                SimCamera::new(view.clone(), sim_peers(rig, controllers)?, routes.to_vec());
            (Box::new(camera), Some(view))
        }
    })
}

fn open_mover(
    rig: &RigFile,
    sim_view: Option<Arc<SimView>>,
) -> anyhow::Result<Option<Box<dyn CameraMover>>> {
    Ok(match &rig.mover {
        None => None,
        Some(MoverSpec::Command { argv, timeout_s }) => Some(Box::new(CommandMover::new(
            argv.clone(),
            Duration::from_secs_f64(*timeout_s),
        ))),
        Some(MoverSpec::Http { url, timeout_s }) => Some(Box::new(HttpMover::new(
            url.clone(),
            Duration::from_secs_f64(*timeout_s),
        )?)),
        Some(MoverSpec::Manual) => Some(Box::new(ManualMover)),
        Some(MoverSpec::Sim) => {
            let view = sim_view.context("mover kind \"sim\" needs camera kind \"sim\"")?;
            Some(Box::new(SimMover(view)))
        }
    })
}

#[async_trait]
impl Rig for LabRig {
    fn task(&self) -> TaskKind {
        self.rig.task
    }

    async fn initial_image(&mut self) -> anyhow::Result<Frame> {
        self.capture().await
    }

    async fn execute(&mut self, action: &Action) -> anyhow::Result<Executed> {
        let mut camera_time_s = 0.0;
        let motor_time_s = match action {
            Action::Michelson { command, .. } => {
                let values: Vec<(usize, i32)> = command.iter().copied().enumerate().collect();
                self.move_axes(&values, false).await?
            }
            Action::Cavity { command, .. } => {
                let values: Vec<(usize, i32)> = command.iter().copied().enumerate().collect();
                self.move_axes(&values, false).await?
            }
            Action::Relay(RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            }) => {
                self.scorer.adjusted(usize::from(*mirror));
                let values = [
                    (axis_of(*mirror, false), *vertical),
                    (axis_of(*mirror, true), *horizontal),
                ];
                self.move_axes(&values, true).await?
            }
            Action::Relay(RelayAction::TiltAll { deltas }) => {
                for (axis, delta) in deltas.iter().enumerate() {
                    if *delta != 0 {
                        self.scorer.adjusted(axis / 2);
                    }
                }
                let values: Vec<(usize, i32)> = deltas.iter().copied().enumerate().collect();
                self.move_axes(&values, true).await?
            }
            Action::Relay(RelayAction::Measure { station }) => {
                if *station != self.station {
                    let mover = self
                        .mover
                        .as_mut()
                        .context("this rig has no camera mover")?;
                    let started = tokio::time::Instant::now();
                    mover.move_to(*station).await.with_context(|| {
                        format!("moving the camera to {station} ({})", mover.describe())
                    })?;
                    tokio::time::sleep(Duration::from_secs_f64(self.rig.settle.after_camera_s))
                        .await;
                    camera_time_s = started.elapsed().as_secs_f64();
                    self.station = *station;
                }
                0.0
            }
            Action::Relay(RelayAction::Done) => 0.0,
        };
        let started = tokio::time::Instant::now();
        let image = self.capture().await?;
        camera_time_s += started.elapsed().as_secs_f64();
        Ok(Executed {
            image,
            motor_time_s,
            camera_time_s,
        })
    }

    async fn emergency_stop(&mut self) -> anyhow::Result<()> {
        let stops = self
            .controllers
            .iter()
            .map(|client| client.emergency_stop());
        reached_all(
            futures::future::join_all(stops).await,
            &self.rig.controllers,
            "the emergency stop",
        )
    }

    async fn controllers(&mut self) -> anyhow::Result<Vec<ControllerView>> {
        let mut views = Vec::with_capacity(self.controllers.len());
        for (client, spec) in self.controllers.iter().zip(&self.rig.controllers) {
            let status = client
                .status()
                .await
                .with_context(|| format!("status of controller {:?}", spec.name))?;
            views.push(ControllerView::from_status(&spec.name, &status));
        }
        Ok(views)
    }

    fn score(&self) -> Score {
        let controller_positions: Vec<f64> = self
            .routes
            .iter()
            .zip(self.origin.iter().zip(&self.commanded))
            .map(|(route, (origin, commanded))| f64::from(origin + route.sign * commanded))
            .collect();
        self.scorer
            .score(&self.task_positions(), &controller_positions)
    }
}
