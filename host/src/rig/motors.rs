//! The simulated firmware behind a [`SimRig`](super::SimRig): either the peer core in the
//! same process (fast, for benchmarks) or a simulated peer reached over loopback TCP through
//! the real protocol client (the full hardware path). Both run the same firmware core with
//! instant simulated time, so the same commands give the same true shaft positions.

use std::sync::Arc;

use anyhow::{Context, bail};
use optalign_firmware::Session;
use optalign_protocol::{
    AxisConfig, AxisValue, Command, MoveOutcome, PeerMessage, Reply, Request, RequestId,
    SoftLimits, Status,
};

use crate::link::{Client, ClientOptions, Endpoint};
use crate::peer::{MechanicsOptions, PeerCore, PeerOptions, SimPeer, TimeMode};
use crate::scenario::MountParams;

/// Which path the rig's motor commands take.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum MotorPath {
    /// The firmware core in this process: fastest.
    InProcess,
    /// A simulated peer on a loopback TCP port, through the protocol client.
    Peer,
}

/// Key the rig provisions on its own peer: a derived key (`hex:`), not a passphrase. A
/// passphrase is stretched with Argon2id (19 MiB, two passes) whenever a controller or a
/// client meets it, so every rig start paid that once in process and twice over loopback:
/// a third of a Python environment's time went into the stretching at its resets.
const RIG_KEY: &str = "hex:54554664107462e39b10354aab854182efa3920f126c926282ac1281874d9637";

/// The simulated controller of a rig (without its key and time): `axes` axes on the
/// mounts `mount` describes, seeded with `seed` for deterministic lost steps.
pub fn rig_peer_options(axes: u8, mount: &MountParams, seed: u64) -> PeerOptions {
    PeerOptions {
        axes,
        mechanics: MechanicsOptions {
            backlash: mount.backlash_steps,
            lost_step_probability: mount.lost_step_probability,
            pitch_error: mount.pitch_error_steps,
            pitch_period: mount.pitch_period_steps,
            hysteresis: mount.hysteresis_steps,
            seed,
            ..MechanicsOptions::default()
        },
        state_file: None,
        ..PeerOptions::default()
    }
}

/// The configuration a rig gives each axis of its controller (from the axis's `current`
/// one): the scenario's speeds and backlash compensation, soft limits far beyond any task's
/// range.
pub fn rig_axis_config(mount: &MountParams, current: AxisConfig) -> AxisConfig {
    AxisConfig {
        max_speed: mount.max_speed,
        acceleration: mount.acceleration,
        backlash: mount.compensation_steps,
        backlash_mode: mount.compensation_mode.into(),
        limits: SoftLimits {
            min: -1_000_000,
            max: 1_000_000,
        },
        ..current
    }
}

/// The simulated controller a rig moves.
pub enum SimMotors {
    InProcess {
        core: Box<PeerCore>,
        session: Box<Session>,
        next_id: u32,
    },
    Peer {
        peer: Arc<SimPeer>,
        client: Box<Client>,
    },
}

impl SimMotors {
    /// Starts a controller with `axes` axes on mounts described by `mount`, seeded for
    /// deterministic lost steps, with compensation and speeds configured on every axis.
    pub async fn start(
        path: MotorPath,
        axes: usize,
        mount: &MountParams,
        seed: u64,
    ) -> anyhow::Result<Self> {
        let options = PeerOptions {
            key: Some(RIG_KEY.into()),
            time: TimeMode::Instant,
            ..rig_peer_options(u8::try_from(axes).context("too many axes")?, mount, seed)
        };
        let mut motors = match path {
            MotorPath::InProcess => {
                let mut core = Box::new(PeerCore::new(&options)?);
                let session = Box::new(core.serial_session());
                Self::InProcess {
                    core,
                    session,
                    next_id: 1,
                }
            }
            MotorPath::Peer => {
                let (peer, address) = SimPeer::start_on_loopback(&options).await?;
                let endpoint = Endpoint::Tcp {
                    host: address.ip().to_string(),
                    port: address.port(),
                };
                let client_options = ClientOptions {
                    key: Some(RIG_KEY.parse()?),
                    ..ClientOptions::default()
                };
                let client = Client::connect(endpoint, client_options).await?;
                Self::Peer {
                    peer,
                    client: Box::new(client),
                }
            }
        };
        for axis in 0..axes as u8 {
            let config = rig_axis_config(mount, motors.config(axis).await?);
            motors.request(Command::SetConfig { axis, config }).await?;
        }
        Ok(motors)
    }

    async fn config(&mut self, axis: u8) -> anyhow::Result<AxisConfig> {
        match self.request(Command::GetConfig { axis }).await? {
            Reply::Config(config) => Ok(config),
            other => bail!("unexpected reply to GetConfig: {other:?}"),
        }
    }

    async fn request(&mut self, command: Command) -> anyhow::Result<Reply> {
        match self {
            Self::InProcess {
                core,
                session,
                next_id,
            } => {
                let request = Request {
                    id: RequestId(*next_id),
                    command,
                };
                *next_id += 1;
                let replies = core.handle(session, &request);
                replies
                    .into_iter()
                    .find_map(|message| match message {
                        PeerMessage::Reply { id, reply } if id == request.id => Some(reply),
                        _ => None,
                    })
                    .map(|reply| match reply {
                        Reply::Error(error) => Err(anyhow::anyhow!("controller refused: {error}")),
                        reply => Ok(reply),
                    })
                    .context("the controller did not answer")?
            }
            Self::Peer { client, .. } => Ok(client.request(command).await?),
        }
    }

    /// Moves to absolute targets (or by deltas) and waits; returns the travel time in s.
    pub async fn travel(&mut self, values: &[AxisValue], relative: bool) -> anyhow::Result<f64> {
        let list = values.iter().copied().collect();
        let command = if relative {
            Command::MoveBy { deltas: list }
        } else {
            Command::MoveTo { targets: list }
        };
        let duration_ms = match self {
            Self::InProcess { .. } => {
                let reply = self.request(command).await?;
                let Reply::MoveStarted { duration_ms } = reply else {
                    bail!("unexpected reply to a move: {reply:?}")
                };
                if let Self::InProcess { core, .. } = self {
                    core.settle();
                }
                duration_ms
            }
            Self::Peer { client, .. } => {
                let id = client.next_request_id();
                let report = client.run_move_with_id(id, command).await?;
                if report.outcome != MoveOutcome::Completed {
                    bail!("move ended early: {:?}", report.outcome);
                }
                report.duration_ms
            }
        };
        Ok(f64::from(duration_ms) / 1000.0)
    }

    /// Emergency stop: the controller ends all motion, cuts the coils and latches.
    pub async fn emergency_stop(&mut self) -> anyhow::Result<()> {
        match self.request(Command::EmergencyStop).await? {
            Reply::Ok => Ok(()),
            other => bail!("unexpected reply to EmergencyStop: {other:?}"),
        }
    }

    /// The controller's status reply.
    pub async fn status(&mut self) -> anyhow::Result<Status> {
        match self.request(Command::Status).await? {
            Reply::Status(status) => Ok(status),
            other => bail!("unexpected reply to Status: {other:?}"),
        }
    }

    /// True shaft positions: hidden truth.
    pub fn shafts(&self) -> Vec<i32> {
        match self {
            Self::InProcess { core, .. } => core.shaft_positions(),
            Self::Peer { peer, .. } => peer.shaft_positions(),
        }
    }
}

impl Drop for SimMotors {
    /// A peer's accept loop holds the peer, so it would outlive the rig on a runtime that
    /// goes on (a Python environment resetting, a bench worker): stop it here.
    fn drop(&mut self) {
        if let Self::Peer { peer, .. } = self {
            peer.shutdown();
        }
    }
}
