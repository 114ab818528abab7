//! `optalign set-position`: declares where idle axes are (re-zeroing; clears a lost position).

use clap::Args;
use optalign_protocol::{AxisValue, Command};

use super::axes::{check_axes, parse_axis_value};
use super::connect::ControllerArgs;

#[derive(Debug, Args)]
pub struct SetPositionArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    /// Where each axis is now, as AXIS=STEPS (logical steps).
    #[arg(required = true, value_name = "AXIS=STEPS", value_parser = parse_axis_value, allow_negative_numbers = true)]
    positions: Vec<AxisValue>,
}

pub async fn run(args: SetPositionArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    check_axes(&args.positions, client.identity().axes)?;
    for value in &args.positions {
        client
            .command_ok(Command::SetPosition {
                axis: value.axis,
                position: value.steps,
            })
            .await
            .map_err(|e| args.controller.explain(e))?;
        crate::say!("axis {}: position set to {}", value.axis, value.steps);
    }
    Ok(())
}
