//! The command line: one subcommand per job, each in its own module.

mod axes;
mod config;
mod connect;
mod motion;
mod peer;
mod provision;
mod render;
mod run;
mod status;

use clap::{Parser, Subcommand};

/// Aligns free-space optics from camera images: motor controllers, simulations, policies.
#[derive(Debug, Parser)]
#[command(name = "optalign", version, about, propagate_version = true)]
pub struct Cli {
    /// More diagnostics on stderr (-v, -vv, -vvv); RUST_LOG overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    command: Commands,
}

#[derive(Debug, Subcommand)]
enum Commands {
    /// Serve a simulated motor controller (the real firmware core on simulated mounts).
    Peer(peer::PeerArgs),
    /// Show a controller's identity and the state of every axis.
    Status(status::StatusArgs),
    /// Move axes to absolute targets (or by relative amounts); returns when motion ends.
    Move(motion::MoveArgs),
    /// Stop all motion: decelerate, or with --emergency cut the coils at once.
    Stop(motion::StopArgs),
    /// Read or change per-axis configuration.
    Config(config::ConfigArgs),
    /// Give a controller Wi-Fi credentials and its access key over USB serial.
    Provision(provision::ProvisionArgs),
    /// Write one camera frame of a simulated scene.
    Render(render::RenderArgs),
    /// Run one alignment task with one policy.
    Run(run::RunArgs),
}

impl Cli {
    pub async fn run(self) -> anyhow::Result<()> {
        match self.command {
            Commands::Peer(args) => peer::run(args).await,
            Commands::Status(args) => status::run(args).await,
            Commands::Move(args) => motion::run_move(args).await,
            Commands::Stop(args) => motion::run_stop(args).await,
            Commands::Config(args) => config::run(args).await,
            Commands::Provision(args) => provision::run(args).await,
            Commands::Render(args) => render::run(args),
            Commands::Run(args) => run::run(args).await,
        }
    }
}

/// Joins an error and its causes into one line, skipping causes already quoted.
pub fn one_line(error: &anyhow::Error) -> String {
    let mut line = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if !line.contains(&cause) {
            line.push_str(": ");
            line.push_str(&cause);
        }
    }
    line
}
