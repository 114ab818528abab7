//! `optalign peer`: run a simulated motor controller until interrupted.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;

use crate::bounds;
use crate::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};

/// The slowest simulated clock: a thousandth of real time (a 1 s move takes 17 minutes).
const MIN_TIME_SCALE: f64 = 1e-3;
/// The fastest scaled clock; beyond it use 0, where moves complete at once.
const MAX_TIME_SCALE: f64 = 1e6;

#[derive(Debug, Args)]
pub struct PeerArgs {
    /// Address to serve the protocol on (loopback by default; a LAN address exposes it).
    #[arg(long, default_value = "127.0.0.1:7878", value_name = "HOST:PORT")]
    listen: SocketAddr,
    /// Number of axes.
    #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u8).range(1..=8))]
    axes: u8,
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
    let options = PeerOptions {
        axes: args.axes,
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
        "simulated controller: {} axes, true backlash {} steps",
        args.axes,
        args.backlash
    );
    crate::say!("listening on tcp://{bound}");
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
