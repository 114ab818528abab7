//! The controller's state as self-describing JSON, schema `optalign.status/1`: faults,
//! boot record, directions and capabilities in words rather than bit masks and Rust
//! variant names, so a script needs no knowledge of the wire format. `optalign status
//! --json` and the Python `Controller.status()` both print this one report; its schema is
//! documented in docs/protocol.md and versioned by its `schema` field.

use optalign_protocol::{
    AxisStatus, BootRecord, Capabilities, Direction, Faults, Identity, Slack, Status,
    StorageFailure,
};
use serde_json::{Value, json};

/// The schema this module writes; a change that removes or renames a field bumps it.
pub const STATUS_SCHEMA: &str = "optalign.status/1";

/// The report of `status` from the controller at `endpoint` that identified as `identity`.
pub fn status_report(endpoint: &str, identity: &Identity, status: &Status) -> Value {
    let positions_lost: Vec<usize> = (0..)
        .zip(&status.axes)
        .filter(|(_, axis)| axis.faults.has(Faults::POSITION_LOST))
        .map(|(index, _)| index)
        .collect();
    json!({
        "schema": STATUS_SCHEMA,
        "controller": endpoint,
        "identity": {
            "board": identity.board.as_str(),
            "firmware_version": identity.firmware_version.as_str(),
            "protocol_version": identity.protocol_version,
            "board_id": format!("{:016x}", identity.board_id),
            "axes": identity.axes,
            "capabilities": capability_names(identity.capabilities),
            "boot_nonce": format!("{:016x}", identity.boot_nonce),
        },
        "session": {
            "link": if status.session.trusted_link { "serial" } else { "network" },
            "authenticated": status.session.authenticated,
            "key_provisioned": status.session.key_provisioned,
        },
        "emergency_stopped": status.emergency_stopped,
        "uptime_ms": status.uptime_ms,
        "boot": boot_name(status.boot),
        "positions_lost": positions_lost,
        "storage": {
            "unsaved": status.storage.unsaved,
            "failed_writes": status.storage.failed_writes,
            "last_failure": status.storage.last_failure.map(|failure| match failure {
                StorageFailure::Write => "write",
                StorageFailure::ReadBack => "read-back",
            }),
        },
        "security": {
            "failed_authentications": status.security.failed_authentications,
            "rejected_frames": status.security.rejected_frames,
        },
        "axes": (0..).zip(&status.axes).map(|(index, axis): (usize, _)| axis_report(index, axis)).collect::<Vec<_>>(),
    })
}

fn axis_report(index: usize, axis: &AxisStatus) -> Value {
    json!({
        "axis": index,
        "position": axis.position,
        "motor_steps": axis.motor_steps,
        "target": axis.target,
        "moving": axis.moving,
        "direction": match axis.direction {
            Direction::Idle => "idle",
            Direction::Positive => "positive",
            Direction::Negative => "negative",
        },
        "slack": match axis.slack {
            Slack::Unknown => "unknown",
            Slack::TakenUpPositive => "taken-up-positive",
            Slack::TakenUpNegative => "taken-up-negative",
        },
        "limits": { "min": axis.limits.min, "max": axis.limits.max },
        "faults": fault_names(axis.faults),
        "powered": axis.powered,
        "underruns": axis.underruns,
    })
}

/// The boot record in words.
pub fn boot_name(boot: BootRecord) -> &'static str {
    match boot {
        BootRecord::NoRecordYet => "no-record-yet",
        BootRecord::Restored => "restored",
        BootRecord::Unreadable => "unreadable",
        BootRecord::InterruptedMove => "interrupted-move",
    }
}

/// Every fault an axis reports, in words; bits this host does not know are named by
/// their number rather than dropped.
pub fn fault_names(faults: Faults) -> Vec<String> {
    const NAMED: [(u8, &str); 3] = [
        (Faults::EMERGENCY_STOP, "emergency-stop"),
        (Faults::DRIVER, "driver"),
        (Faults::POSITION_LOST, "position-lost"),
    ];
    named_bits(
        u32::from(faults.0),
        &NAMED.map(|(bit, name)| (u32::from(bit), name)),
    )
}

fn capability_names(capabilities: Capabilities) -> Vec<String> {
    named_bits(
        capabilities.0,
        &[
            (Capabilities::UNIPOLAR_HALF_STEP, "unipolar-half-step"),
            (Capabilities::STEP_DIR, "step-dir"),
            (Capabilities::PERSISTENCE, "persistence"),
            (Capabilities::WIFI, "wifi"),
            (Capabilities::SERIAL, "serial"),
            (Capabilities::SIMULATED, "simulated"),
        ],
    )
}

/// The names of the set bits of `mask`; an unnamed bit becomes `bit-N`.
fn named_bits(mask: u32, names: &[(u32, &str)]) -> Vec<String> {
    (0..32)
        .map(|bit| 1u32 << bit)
        .filter(|flag| mask & flag != 0)
        .map(
            |flag| match names.iter().find(|(named, _)| *named == flag) {
                Some((_, name)) => (*name).to_owned(),
                None => format!("bit-{}", flag.trailing_zeros()),
            },
        )
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_and_capabilities_are_named_and_unknown_bits_kept() {
        assert_eq!(fault_names(Faults(0)), Vec::<String>::new());
        assert_eq!(
            fault_names(Faults(
                Faults::POSITION_LOST | Faults::EMERGENCY_STOP | 0x80
            )),
            ["emergency-stop", "position-lost", "bit-7"]
        );
        assert_eq!(
            capability_names(Capabilities(Capabilities::WIFI | Capabilities::STEP_DIR)),
            ["step-dir", "wifi"]
        );
        assert_eq!(boot_name(BootRecord::InterruptedMove), "interrupted-move");
    }
}
