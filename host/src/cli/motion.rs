//! `optalign move`, `optalign stop` and `optalign clear-emergency`.

use std::time::Duration;

use anyhow::{Context, bail};
use clap::Args;
use optalign_protocol::{AxisValue, Command, ErrorCode, MoveOutcome};

use crate::link::client::emergency_stop;
use crate::link::{Client, ClientError};

use super::axes::{check_axes, parse_axis_value};
use super::connect::ControllerArgs;

#[derive(Debug, Args)]
pub struct MoveArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    /// Targets as AXIS=STEPS (absolute logical steps, or deltas with --relative).
    #[arg(required = true, value_name = "AXIS=STEPS", value_parser = parse_axis_value, allow_negative_numbers = true)]
    targets: Vec<AxisValue>,
    /// Treat the values as relative moves.
    #[arg(long)]
    relative: bool,
}

pub async fn run_move(args: MoveArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    check_axes(&args.targets, client.identity().axes)?;
    let report = if args.relative {
        client.move_by(&args.targets).await
    } else {
        client.move_to(&args.targets).await
    }
    .map_err(|e| args.controller.explain(e))?;
    let positions: Vec<String> = report
        .positions
        .iter()
        .enumerate()
        .map(|(axis, position)| format!("{axis}={position}"))
        .collect();
    match report.outcome {
        MoveOutcome::Completed => {
            crate::say!("move completed: {}", positions.join(" "));
            Ok(())
        }
        other => bail!("move ended early ({other:?}) at {}", positions.join(" ")),
    }
}

/// The pause between two tries of `optalign stop`.
const STOP_RETRY: Duration = Duration::from_millis(50);

#[derive(Debug, Args)]
pub struct StopArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    /// Stop at once and switch the coils off instead of decelerating.
    #[arg(long)]
    emergency: bool,
}

/// Stops, trying again (a new connection each time) until the deadline (`--deadline-ms`):
/// a controller restarting, or busy with strangers' connections, still gets the stop.
pub async fn run_stop(args: StopArgs) -> anyhow::Result<()> {
    let options = args.controller.options()?;
    let endpoint = &args.controller.controller;
    if args.emergency {
        // Open to everyone: no key, no authentication to wait for.
        emergency_stop(endpoint, &options)
            .await
            .map_err(|e| args.controller.explain(e))
            .with_context(|| format!("emergency stop of {endpoint}"))?;
        crate::say!(
            "emergency stop: all axes stopped, coils off; moves are refused until `optalign clear-emergency`"
        );
        return Ok(());
    }
    let deadline = tokio::time::Instant::now() + options.deadline;
    loop {
        let attempt = async {
            Client::connect(endpoint.clone(), options.clone())
                .await?
                .command_ok(Command::Stop)
                .await
        };
        let error = match tokio::time::timeout_at(deadline, attempt).await {
            Ok(Ok(())) => break,
            Ok(Err(error)) => error,
            Err(_) => bail!("stop of {endpoint}: no answer within --deadline-ms"),
        };
        let lasting = matches!(
            error,
            ClientError::VersionMismatch { .. } | ClientError::Impostor { .. }
        ) || error.code().is_some_and(|code| code != ErrorCode::BUSY);
        if lasting || tokio::time::Instant::now() + STOP_RETRY >= deadline {
            return Err(args.controller.explain(error))
                .with_context(|| format!("stop of {endpoint}"));
        }
        tracing::debug!(%error, "stop not through yet; trying again");
        tokio::time::sleep(STOP_RETRY).await;
    }
    crate::say!("stop: all axes decelerating to rest");
    Ok(())
}

#[derive(Debug, Args)]
pub struct ClearEmergencyArgs {
    #[command(flatten)]
    controller: ControllerArgs,
}

pub async fn run_clear_emergency(args: ClearEmergencyArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    client
        .command_ok(Command::ClearEmergency)
        .await
        .map_err(|e| args.controller.explain(e))?;
    crate::say!(
        "emergency latch cleared: moves are accepted again (coils power up with the next move)"
    );
    Ok(())
}
