//! Parsing `AXIS=VALUE` arguments and checking them against a controller.

use anyhow::bail;
use optalign_protocol::AxisValue;

/// Parses `AXIS=STEPS`, e.g. `0=2000` or `1=-1500`.
pub fn parse_axis_value(text: &str) -> Result<AxisValue, String> {
    let (axis, steps) = text
        .split_once('=')
        .ok_or_else(|| format!("expected AXIS=STEPS (like 0=2000), got {text:?}"))?;
    let axis = axis
        .trim()
        .parse::<u8>()
        .map_err(|_| format!("axis {axis:?} in {text:?} is not an axis number (0, 1, ...)"))?;
    let steps = steps
        .trim()
        .parse::<i32>()
        .map_err(|_| format!("steps {steps:?} in {text:?} is not a whole number of steps"))?;
    Ok(AxisValue { axis, steps })
}

/// Rejects unknown and repeated axes before anything is sent.
pub fn check_axes(values: &[AxisValue], axis_count: u8) -> anyhow::Result<()> {
    for (i, value) in values.iter().enumerate() {
        if value.axis >= axis_count {
            bail!(
                "unknown axis {}: this controller has axes 0..={}",
                value.axis,
                axis_count.saturating_sub(1)
            );
        }
        if values[..i].iter().any(|v| v.axis == value.axis) {
            bail!("axis {} is given twice", value.axis);
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_and_explains() {
        assert_eq!(
            parse_axis_value("1=-1500"),
            Ok(AxisValue {
                axis: 1,
                steps: -1500
            })
        );
        assert!(
            parse_axis_value("x=1")
                .unwrap_err()
                .contains("not an axis number")
        );
        assert!(
            parse_axis_value("1=1.5")
                .unwrap_err()
                .contains("whole number")
        );
        assert!(parse_axis_value("12").unwrap_err().contains("AXIS=STEPS"));
    }

    #[test]
    fn unknown_and_repeated_axes_are_refused() {
        let ok = [
            AxisValue { axis: 0, steps: 1 },
            AxisValue { axis: 1, steps: 2 },
        ];
        assert!(check_axes(&ok, 2).is_ok());
        assert!(
            check_axes(&ok, 1)
                .unwrap_err()
                .to_string()
                .contains("unknown axis 1")
        );
        let twice = [
            AxisValue { axis: 0, steps: 1 },
            AxisValue { axis: 0, steps: 2 },
        ];
        assert!(
            check_axes(&twice, 4)
                .unwrap_err()
                .to_string()
                .contains("twice")
        );
    }
}
