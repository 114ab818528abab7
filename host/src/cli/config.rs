//! `optalign config`: read and change per-axis configuration.

use anyhow::{Context, bail};
use clap::{Args, Subcommand};
use optalign_protocol::{Approach, AxisConfig, BacklashMode, Command, DriverKind};

use super::connect::ControllerArgs;

#[derive(Debug, Args)]
pub struct ConfigArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    #[command(subcommand)]
    action: ConfigAction,
}

#[derive(Debug, Subcommand)]
enum ConfigAction {
    /// Print the configuration of one axis, or of all axes.
    Get {
        /// Axis number; all axes when omitted.
        axis: Option<u8>,
        /// Print JSON.
        #[arg(long)]
        json: bool,
    },
    /// Change fields of one axis: KEY=VALUE ... (see `docs/protocol.md` for the keys).
    Set {
        axis: u8,
        /// max_speed, acceleration, backlash, backlash_mode (off|one-sided|take-up),
        /// approach (positive|negative), overshoot_margin, min, max, invert (true|false),
        /// idle_power_down_ms, driver (half-step|step-dir).
        #[arg(required = true, value_name = "KEY=VALUE")]
        fields: Vec<String>,
        /// Also persist configuration and positions to the controller's flash.
        #[arg(long)]
        save: bool,
    },
}

pub async fn run(args: ConfigArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    let axes = client.identity().axes;
    match args.action {
        ConfigAction::Get { axis, json } => {
            let selected: Vec<u8> = match axis {
                Some(axis) if axis >= axes => bail!(
                    "unknown axis {axis}: this controller has axes 0..={}",
                    axes.saturating_sub(1)
                ),
                Some(axis) => vec![axis],
                None => (0..axes).collect(),
            };
            let mut configs = Vec::new();
            for axis in selected {
                configs.push((axis, client.get_config(axis).await?));
            }
            if json {
                let value: Vec<_> = configs
                    .iter()
                    .map(|(axis, config)| serde_json::json!({ "axis": axis, "config": config }))
                    .collect();
                crate::say!("{}", serde_json::to_string_pretty(&value)?);
            } else {
                for (axis, config) in &configs {
                    crate::say!("axis {axis}: {}", describe(config));
                }
            }
        }
        ConfigAction::Set { axis, fields, save } => {
            if axis >= axes {
                bail!(
                    "unknown axis {axis}: this controller has axes 0..={}",
                    axes.saturating_sub(1)
                );
            }
            let mut config = client.get_config(axis).await?;
            for field in &fields {
                apply_field(&mut config, field)?;
            }
            let explain = |e| args.controller.explain(e);
            client
                .command_ok(Command::SetConfig { axis, config })
                .await
                .map_err(explain)?;
            if save {
                client
                    .command_ok(Command::SaveConfig)
                    .await
                    .map_err(explain)?;
            }
            crate::say!(
                "axis {axis}: {}{}",
                describe(&config),
                if save { " (saved)" } else { "" }
            );
        }
    }
    Ok(())
}

/// One line of `key=value` pairs, in the same spelling `config set` accepts.
pub fn describe(config: &AxisConfig) -> String {
    format!(
        "max_speed={} acceleration={} backlash={} backlash_mode={} approach={} overshoot_margin={} min={} max={} invert={} idle_power_down_ms={} driver={}",
        config.max_speed,
        config.acceleration,
        config.backlash,
        match config.backlash_mode {
            BacklashMode::Off => "off",
            BacklashMode::OneSided => "one-sided",
            BacklashMode::TakeUp => "take-up",
        },
        match config.approach {
            Approach::Positive => "positive",
            Approach::Negative => "negative",
        },
        config.overshoot_margin,
        config.limits.min,
        config.limits.max,
        config.invert,
        config.idle_power_down_ms,
        match config.driver {
            DriverKind::UnipolarHalfStep => "half-step",
            DriverKind::StepDir => "step-dir",
        },
    )
}

/// Applies one `key=value` to a configuration.
pub fn apply_field(config: &mut AxisConfig, field: &str) -> anyhow::Result<()> {
    let (key, value) = field
        .split_once('=')
        .with_context(|| format!("expected KEY=VALUE, got {field:?}"))?;
    let number = |what: &str| -> anyhow::Result<i64> {
        value
            .parse::<i64>()
            .with_context(|| format!("{key} must be a whole number ({what}), got {value:?}"))
    };
    let ranged = |what: &str, max: i64| -> anyhow::Result<i64> {
        let n = number(what)?;
        if !(0..=max).contains(&n) {
            bail!("{key} must be within 0..={max} ({what}), got {n}");
        }
        Ok(n)
    };
    match key {
        "max_speed" => config.max_speed = ranged("steps/s", u32::MAX.into())? as u32,
        "acceleration" => config.acceleration = ranged("steps/s²", u32::MAX.into())? as u32,
        "backlash" => config.backlash = ranged("steps", u16::MAX.into())? as u16,
        "overshoot_margin" => config.overshoot_margin = ranged("steps", u16::MAX.into())? as u16,
        "idle_power_down_ms" => config.idle_power_down_ms = ranged("ms", u32::MAX.into())? as u32,
        "min" | "max" => {
            let n = i32::try_from(number("steps")?)
                .with_context(|| format!("{key} is out of range"))?;
            if key == "min" {
                config.limits.min = n
            } else {
                config.limits.max = n
            }
        }
        "invert" => {
            config.invert = value
                .parse()
                .with_context(|| format!("invert must be true or false, got {value:?}"))?
        }
        "backlash_mode" => {
            config.backlash_mode = match value {
                "off" => BacklashMode::Off,
                "one-sided" => BacklashMode::OneSided,
                "take-up" => BacklashMode::TakeUp,
                _ => bail!("backlash_mode must be off, one-sided or take-up, got {value:?}"),
            }
        }
        "approach" => {
            config.approach = match value {
                "positive" => Approach::Positive,
                "negative" => Approach::Negative,
                _ => bail!("approach must be positive or negative, got {value:?}"),
            }
        }
        "driver" => {
            config.driver = match value {
                "half-step" => DriverKind::UnipolarHalfStep,
                "step-dir" => DriverKind::StepDir,
                _ => bail!("driver must be half-step or step-dir, got {value:?}"),
            }
        }
        _ => bail!(
            "unknown configuration key {key:?}: use max_speed, acceleration, backlash, backlash_mode, approach, overshoot_margin, min, max, invert, idle_power_down_ms or driver"
        ),
    }
    Ok(())
}
