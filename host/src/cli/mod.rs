//! The command line: one subcommand per job, each in its own module.

pub mod axes;
mod beams;
mod bench;
mod calibrate;
mod cameras;
pub mod config;
pub mod connect;
mod demo;
mod flash;
mod jog;
mod monitor;
mod motion;
mod peer;
mod position;
mod provision;
mod render;
mod replay;
mod rezero;
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
    /// Drive a bench by hand while looking: keys move an axis by a step, the camera's beams
    /// are read out live.
    Jog(jog::JogArgs),
    /// Stop all motion: decelerate, or with --emergency cut the coils at once and latch.
    Stop(motion::StopArgs),
    /// Release the emergency latch so that moves are accepted again.
    ClearEmergency(motion::ClearEmergencyArgs),
    /// Declare where idle axes are (re-zero them); clears a lost position.
    SetPosition(position::SetPositionArgs),
    /// Read or change per-axis configuration.
    Config(config::ConfigArgs),
    /// Give a controller Wi-Fi credentials and its access key over USB serial.
    Provision(provision::ProvisionArgs),
    /// Turn the firmware into a UF2 image and copy it onto a board in BOOTSEL mode.
    Flash(flash::FlashArgs),
    /// Calibrate a bench from its camera: a mirror's response or an axis's backlash.
    Calibrate(calibrate::CalibrateArgs),
    /// Find axes whose position was lost (power cut mid-move) from the camera and the
    /// response calibration, and declare them.
    Rezero(rezero::RezeroArgs),
    /// Write one camera frame of a simulated scene.
    Render(render::RenderArgs),
    /// Find the beams in an image file: centres, how sure, sizes, and what is wrong with each.
    Beams(beams::BeamsArgs),
    /// List the camera kinds this build reads and the V4L2 cameras found.
    Cameras(cameras::CamerasArgs),
    /// Run one alignment task with one policy.
    Run(run::RunArgs),
    /// Run the task x policy x seed matrix on simulated rigs; write results, summary, charts.
    Bench(bench::BenchArgs),
    /// Align all three simulated tasks through the simulated firmware; write an HTML report.
    Demo(demo::DemoArgs),
    /// Serve the page of a finished run (transcript and frames) with a slider over its
    /// evaluations.
    Monitor(monitor::MonitorCommandArgs),
    /// Re-run a recorded vlm run's replies on the simulator, without calling the model.
    Replay(replay::ReplayArgs),
    /// Serve a local OpenAI-compatible test server (request checks, scripted answers).
    #[command(hide = true)]
    FakeLlm(crate::policy::vlm::fake::FakeLlmArgs),
}

impl Cli {
    pub async fn run(self) -> anyhow::Result<()> {
        match self.command {
            Commands::Peer(args) => peer::run(args).await,
            Commands::Status(args) => status::run(args).await,
            Commands::Move(args) => motion::run_move(args).await,
            Commands::Jog(args) => jog::run(args).await,
            Commands::Stop(args) => motion::run_stop(args).await,
            Commands::ClearEmergency(args) => motion::run_clear_emergency(args).await,
            Commands::SetPosition(args) => position::run(args).await,
            Commands::Config(args) => config::run(args).await,
            Commands::Provision(args) => provision::run(args).await,
            Commands::Flash(args) => flash::run(args),
            Commands::Calibrate(args) => calibrate::run(args).await,
            Commands::Rezero(args) => rezero::run(args).await,
            Commands::Render(args) => render::run(args),
            Commands::Beams(args) => beams::run(args),
            Commands::Cameras(args) => cameras::run(args),
            Commands::Run(args) => run::run(args).await,
            Commands::Bench(args) => bench::run(args).await,
            Commands::Demo(args) => demo::run(args).await,
            Commands::Monitor(args) => monitor::run(args).await,
            Commands::Replay(args) => replay::run(args).await,
            Commands::FakeLlm(args) => crate::policy::vlm::fake::run_cli(args).await,
        }
    }
}
