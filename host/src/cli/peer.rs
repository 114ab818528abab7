//! `optalign peer`: run a simulated motor controller until interrupted; with `--scene` it
//! is the whole rehearsal bench (motors, and the camera and camera mover over HTTP).

use std::net::SocketAddr;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use crate::bounds;
use crate::lab::rehearsal;
use crate::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};
use crate::task::TaskKind;

/// The slowest simulated clock: a thousandth of real time (a 1 s move takes 17 minutes).
const MIN_TIME_SCALE: f64 = 1e-3;
/// The fastest scaled clock; beyond it use 0, where moves complete at once.
const MAX_TIME_SCALE: f64 = 1e6;

#[derive(Debug, Args)]
pub struct PeerArgs {
    /// Address to serve the protocol on (loopback by default; a LAN address exposes it).
    #[arg(long, default_value = "127.0.0.1:7878", value_name = "HOST:PORT")]
    listen: SocketAddr,
    /// Number of axes [default: 4, or the scene's axes with --scene]; with --scene, axes
    /// past the scene's move no mirror (a motor that is not wired).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=8))]
    axes: Option<u8>,
    /// Be the whole bench of this task: also serve the camera (frames rendered from the
    /// true shafts) and, for the relay, the camera mover over HTTP (docs/lab.md, section 7).
    #[arg(long, value_name = "TASK")]
    scene: Option<TaskKind>,
    /// The scene's seed: its hidden initial misalignment.
    #[arg(long, default_value_t = 0, requires = "scene")]
    seed: u64,
    /// Scenario file with the scene's parameters; defaults when omitted.
    #[arg(long, value_name = "FILE", requires = "scene")]
    scenario: Option<PathBuf>,
    /// Address to serve the camera on (loopback by default; port 0 picks a free one).
    #[arg(
        long,
        default_value = "127.0.0.1:7879",
        value_name = "HOST:PORT",
        requires = "scene"
    )]
    camera_listen: SocketAddr,
    /// Write a rig file for this bench (controller, axes, camera, mover) to FILE.
    #[arg(long, value_name = "FILE", requires = "scene")]
    write_rig: Option<PathBuf>,
    /// True mechanical backlash (dead band) of every simulated mount, in steps.
    #[arg(long, default_value_t = 0)]
    backlash: u32,
    /// Probability that a step is lost by the mount (0..1).
    #[arg(long, default_value_t = 0.0)]
    lost_steps: f64,
    /// Also serve the trusted serial link on a pseudo-terminal and print its path.
    #[arg(long)]
    pty: bool,
    /// Access key to provision at start (as `optalign provision --key` would over serial).
    #[arg(long, env = "OPTALIGN_PEER_KEY", hide_env_values = true)]
    key: Option<String>,
    /// File that keeps the controller's flash image across restarts; the mounts' true
    /// state is kept apart in FILE.mounts.json, so a killed peer is a faithful power cut.
    #[arg(long, value_name = "FILE")]
    state: Option<PathBuf>,
    /// Simulated time runs this many times faster than real time; 0 completes moves instantly.
    #[arg(long, default_value_t = 1.0)]
    time_scale: f64,
    /// Network clients served at once (1..=16); when all are taken, a newcomer evicts an
    /// unauthenticated client, or may only stop the motors if every one authenticated.
    #[arg(long, default_value_t = 4)]
    max_clients: usize,
}

pub async fn run(args: PeerArgs) -> anyhow::Result<()> {
    anyhow::ensure!(
        (0.0..=1.0).contains(&args.lost_steps),
        "--lost-steps must be a probability in 0..1, got {}",
        args.lost_steps
    );
    if args.time_scale != 0.0 {
        bounds::number_in(
            "--time-scale",
            args.time_scale,
            MIN_TIME_SCALE,
            MAX_TIME_SCALE,
            "times real time (or 0 for instant moves)",
        )
        .map_err(anyhow::Error::msg)?;
    }
    let scene_axes = args.scene.map(rehearsal::scene_axes);
    let axes = match (args.axes, scene_axes) {
        (Some(axes), Some(needed)) if usize::from(axes) < needed => anyhow::bail!(
            "--axes {axes}: the {} scene needs {needed}",
            args.scene.map_or(String::new(), |t| t.to_string())
        ),
        (Some(axes), _) => axes,
        (None, Some(needed)) => needed as u8,
        (None, None) => 4,
    };
    let view = args
        .scene
        .map(|task| rehearsal::sim_view(task, args.scenario.as_deref(), args.seed))
        .transpose()?;
    let options = PeerOptions {
        axes,
        mechanics: MechanicsOptions {
            backlash: args.backlash,
            lost_step_probability: args.lost_steps,
            ..MechanicsOptions::default()
        },
        key: args.key.clone(),
        state_file: args.state.clone(),
        time: if args.time_scale == 0.0 {
            TimeMode::Instant
        } else {
            TimeMode::Scaled(args.time_scale)
        },
        max_clients: args.max_clients,
    };
    let peer = SimPeer::start(&options)?;
    let bound = peer.listen_tcp(args.listen).await?;
    crate::say!(
        "simulated controller: {axes} axes, true backlash {} steps",
        args.backlash
    );
    crate::say!("listening on tcp://{bound}");
    if let (Some(task), Some(view)) = (args.scene, view) {
        let camera = rehearsal::serve(args.camera_listen, peer.clone(), view, task).await?;
        crate::say!(
            "{task} scene (seed {}): camera on http://{camera}/frame{}",
            args.seed,
            if task == TaskKind::Relay {
                format!(", camera mover on http://{camera}/station")
            } else {
                String::new()
            }
        );
        if let Some(path) = &args.write_rig {
            std::fs::write(path, rehearsal::rig_file_text(task, bound, camera))
                .with_context(|| format!("cannot write the rig file {}", path.display()))?;
            crate::say!("rig file: {}", path.display());
        }
    }
    if args.pty {
        crate::say!("serial link on serial://{}", peer.open_pty()?);
    }
    if args.key.is_none() {
        crate::say!(
            "no access key: motion over TCP is refused until one is provisioned (--key, or `optalign provision` over the pty)"
        );
    }
    tokio::signal::ctrl_c().await?;
    peer.shutdown();
    Ok(())
}
