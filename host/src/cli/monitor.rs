//! `--monitor [ADDR]` for `run` and `bench`, and `optalign monitor RUN_DIR`: serving the live
//! page of a run (or a bench's matrix), or the page of a finished run with a slider over its
//! evaluations.

use std::net::SocketAddr;
use std::path::PathBuf;

use clap::Args;

use crate::monitor::{Access, Hub, MonitorServer, RunMonitor, load_recorded, start};

/// Where the monitor listens when `--monitor` names no address.
pub const DEFAULT_MONITOR: &str = "127.0.0.1:8787";

/// Options of the live monitor.
#[derive(Debug, Args)]
pub struct MonitorArgs {
    /// Serve a live page of the run in the browser, with pause and emergency stop, at this
    /// address [default: 127.0.0.1:8787]. Any address other than loopback requires the
    /// random token printed in the URL on every request.
    #[arg(long, value_name = "ADDR", num_args = 0..=1, default_missing_value = DEFAULT_MONITOR)]
    monitor: Option<SocketAddr>,
    /// Require the monitor's token even on a loopback address.
    #[arg(long, requires = "monitor")]
    monitor_token: bool,
}

impl MonitorArgs {
    pub fn is_on(&self) -> bool {
        self.monitor.is_some()
    }

    /// The run's monitor when `--monitor` was given, held before its first action when
    /// `paused`.
    pub fn run_monitor(&self, label: &str, paused: bool) -> Option<RunMonitor> {
        self.monitor?;
        let monitor = RunMonitor::new(label);
        if paused {
            monitor
                .set_paused(true)
                .expect("a run that has not started can be paused");
        }
        Some(monitor)
    }

    /// Starts the server for `hub` when `--monitor` was given, and prints its URL.
    pub async fn serve(&self, hub: &Hub) -> anyhow::Result<Option<MonitorServer>> {
        let Some(address) = self.monitor else {
            return Ok(None);
        };
        let server = serve_hub(address, self.monitor_token, hub.clone()).await?;
        Ok(Some(server))
    }
}

async fn serve_hub(
    address: SocketAddr,
    force_token: bool,
    hub: Hub,
) -> anyhow::Result<MonitorServer> {
    let access = Access::for_address(address, force_token);
    let server = start(address, hub, access).await?;
    eprintln!("monitor: {}", server.url);
    Ok(server)
}

/// `optalign monitor RUN_DIR`.
#[derive(Debug, Args)]
pub struct MonitorCommandArgs {
    /// A run folder (with transcript.jsonl, and frames/ when its frames were saved).
    run_dir: PathBuf,
    /// Address to serve the page on; any address other than loopback requires the token
    /// printed in the URL.
    #[arg(long, value_name = "ADDR", default_value = DEFAULT_MONITOR)]
    listen: SocketAddr,
    /// Require the token even on a loopback address.
    #[arg(long)]
    token: bool,
}

/// Serves a finished run's page until interrupted.
pub async fn run(args: MonitorCommandArgs) -> anyhow::Result<()> {
    let recorded = load_recorded(&args.run_dir)?;
    let _server = serve_hub(args.listen, args.token, Hub::single(recorded)).await?;
    eprintln!("serving {} until Ctrl-C", args.run_dir.display());
    tokio::signal::ctrl_c().await?;
    Ok(())
}
