//! `optalign move`, `optalign stop` and `optalign clear-emergency`.

use anyhow::bail;
use clap::Args;
use optalign_protocol::{AxisValue, Command, MoveOutcome};

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

#[derive(Debug, Args)]
pub struct StopArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    /// Stop at once and switch the coils off instead of decelerating.
    #[arg(long)]
    emergency: bool,
}

pub async fn run_stop(args: StopArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    if args.emergency {
        client
            .command_ok(Command::EmergencyStop)
            .await
            .map_err(|e| args.controller.explain(e))?;
        crate::say!(
            "emergency stop: all axes stopped, coils off; moves are refused until `optalign clear-emergency`"
        );
    } else {
        client
            .command_ok(Command::Stop)
            .await
            .map_err(|e| args.controller.explain(e))?;
        crate::say!("stop: all axes decelerating to rest");
    }
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
