//! `optalign status`: identity and per-axis state, as a table or JSON.

use clap::Args;
use optalign_protocol::{
    AxisStatus, BootRecord, Direction, Faults, Identity, SecurityCounters, Slack, Status,
    StorageFailure, StorageHealth,
};

use crate::console::escape_controls;
use crate::link::report::status_report;

use super::connect::ControllerArgs;

#[derive(Debug, Args)]
pub struct StatusArgs {
    #[command(flatten)]
    controller: ControllerArgs,
    /// Print machine-readable JSON instead of a table.
    #[arg(long)]
    json: bool,
}

pub async fn run(args: StatusArgs) -> anyhow::Result<()> {
    let client = args.controller.connect().await?;
    let status = client.status().await?;
    let identity = client.identity();
    if args.json {
        let report = status_report(&client.endpoint().to_string(), &identity, &status);
        crate::say!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        let table = render_table(&client.endpoint().to_string(), &identity, &status);
        // The board's name and version come from the controller: outside text.
        crate::say!("{}", escape_controls(table.trim_end()));
    }
    Ok(())
}

fn render_table(endpoint: &str, identity: &Identity, status: &Status) -> String {
    let session = status.session;
    let mut out = format!(
        "{endpoint}: {} firmware {}, protocol {}, {} axes, board id {:016x}\n",
        identity.board,
        identity.firmware_version,
        identity.protocol_version,
        identity.axes,
        identity.board_id
    );
    out += &format!(
        "link: {}, authenticated: {}, key provisioned: {}{}\n",
        if session.trusted_link {
            "serial (trusted)"
        } else {
            "network"
        },
        yes_no(session.authenticated),
        yes_no(session.key_provisioned),
        if status.emergency_stopped {
            ", EMERGENCY STOP latched"
        } else {
            ""
        },
    );
    out += match status.boot {
        BootRecord::NoRecordYet => {
            "record: none yet (nothing saved on this controller): positions start at 0 by assumption\n"
        }
        BootRecord::Restored => "record: restored at start-up\n",
        BootRecord::Unreadable => "record: unreadable at start-up: positions lost\n",
        BootRecord::InterruptedMove => {
            "record: the controller was reset during a move: positions of the moving axes lost\n"
        }
    };
    out += &describe_storage(&status.storage);
    out += &describe_security(&status.security);
    out += &describe_underruns(&status.axes);
    let lost: Vec<String> = (0..)
        .zip(&status.axes)
        .filter(|(_, axis)| axis.faults.has(Faults::POSITION_LOST))
        .map(|(index, _): (usize, _)| index.to_string())
        .collect();
    if !lost.is_empty() {
        out += &format!(
            "POSITION LOST on axis {}: moves are refused until you declare where it is with `optalign set-position AXIS=STEPS`\n",
            lost.join(", ")
        );
    }
    out += "axis  position     motor    target  moving  dir  slack  limits                 coils  faults\n";
    for (index, axis) in status.axes.iter().enumerate() {
        out += &axis_row(index, axis);
    }
    out
}

fn axis_row(index: usize, axis: &AxisStatus) -> String {
    let direction = match axis.direction {
        Direction::Idle => ".",
        Direction::Positive => "+",
        Direction::Negative => "-",
    };
    let slack = match axis.slack {
        Slack::Unknown => "?",
        Slack::TakenUpPositive => "+",
        Slack::TakenUpNegative => "-",
    };
    format!(
        "{index:>4}  {:>8}  {:>8}  {:>8}  {:>6}  {:>3}  {:>5}  [{:>9}, {:>9}]  {:>5}  {}\n",
        axis.position,
        axis.motor_steps,
        axis.target,
        yes_no(axis.moving),
        direction,
        slack,
        axis.limits.min,
        axis.limits.max,
        if axis.powered { "on" } else { "off" },
        describe_faults(axis.faults),
    )
}

/// The storage line: whether everything saved is stored, and how writes failed.
fn describe_storage(health: &StorageHealth) -> String {
    let state = if health.unsaved {
        "UNSAVED changes: a write waits for the axes to stop, or failed (saving again retries)"
    } else {
        "everything saved is stored"
    };
    let failures = match (health.failed_writes, health.last_failure) {
        (0, _) => String::new(),
        (count, last) => format!(
            ", {count} failed write{} since start-up (last: {})",
            if count == 1 { "" } else { "s" },
            match last {
                Some(StorageFailure::Write) => "the device failed the write",
                Some(StorageFailure::ReadBack) => "read back different bytes",
                None => "in the background",
            }
        ),
    };
    format!("storage: {state}{failures}\n")
}

/// The network security line: failed authentications and frames dropped by the seal check.
fn describe_security(counters: &SecurityCounters) -> String {
    let plural = |count: u32| if count == 1 { "" } else { "s" };
    let failed = counters.failed_authentications;
    let rejected = counters.rejected_frames;
    format!(
        "network: {failed} failed authentication{} and {rejected} rejected frame{} (bad MAC, replay or no MAC) since start-up\n",
        plural(failed),
        plural(rejected)
    )
}

/// The step timing line, only when an axis's step engine ran out of steps mid-move.
fn describe_underruns(axes: &[AxisStatus]) -> String {
    let late: Vec<String> = (0..)
        .zip(axes)
        .filter(|(_, axis)| axis.underruns > 0)
        .map(|(index, axis): (usize, _)| match axis.underruns {
            1 => format!("axis {index} once"),
            count => format!("axis {index} {count} times"),
        })
        .collect();
    if late.is_empty() {
        return String::new();
    }
    format!(
        "STEP TIMING: the step engine ran out of queued steps mid-move ({}) since start-up: the steps after came late, none was lost\n",
        late.join(", ")
    )
}

fn yes_no(value: bool) -> &'static str {
    if value { "yes" } else { "no" }
}

/// Names the fault bits, or "none".
pub fn describe_faults(faults: Faults) -> String {
    let names = crate::rig::fault_names(faults);
    if names.is_empty() {
        "none".into()
    } else {
        names.join(",")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_storage_line_says_what_is_unsaved_and_how_writes_failed() {
        assert_eq!(
            describe_storage(&StorageHealth::default()),
            "storage: everything saved is stored\n"
        );
        let line = describe_storage(&StorageHealth {
            unsaved: true,
            failed_writes: 2,
            last_failure: Some(StorageFailure::ReadBack),
        });
        assert!(line.contains("UNSAVED"), "{line}");
        assert!(
            line.contains("2 failed writes since start-up (last: read back different bytes)"),
            "{line}"
        );
    }

    #[test]
    fn the_network_line_counts_failed_authentications_and_rejected_frames() {
        assert_eq!(
            describe_security(&SecurityCounters {
                failed_authentications: 1,
                rejected_frames: 3,
            }),
            "network: 1 failed authentication and 3 rejected frames (bad MAC, replay or no MAC) since start-up\n"
        );
    }

    #[test]
    fn the_step_timing_line_names_the_axes_that_ran_out_and_only_them() {
        let axis = |underruns| AxisStatus {
            position: 0,
            motor_steps: 0,
            target: 0,
            moving: false,
            direction: Direction::Idle,
            slack: Slack::Unknown,
            limits: optalign_protocol::SoftLimits { min: -1, max: 1 },
            faults: Faults(0),
            powered: false,
            underruns,
        };
        assert_eq!(describe_underruns(&[axis(0), axis(0)]), "");
        let line = describe_underruns(&[axis(0), axis(2), axis(0), axis(1)]);
        assert!(line.contains("(axis 1 2 times, axis 3 once)"), "{line}");
    }
}
