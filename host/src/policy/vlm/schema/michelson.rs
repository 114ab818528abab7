//! The Michelson reply: descriptions, a verification state, four absolute settings and done.

use serde_json::Value;

use super::{Check, Parsed, extract_object};
use crate::task::Action;
use crate::task::michelson::AXIS_NAMES;

const FIELDS: [&str; 6] = [
    "visual_description",
    "thought_process",
    "command_response",
    "verification_state",
    "command",
    "done",
];

const STATE_FIELDS: [&str; 4] = ["phase", "mirror_1_beam", "mirror_2_beam", "next_test"];

/// The phases the agent may report.
pub const PHASES: [&str; 6] = [
    "search", "identify", "bracket", "refine", "return", "verified",
];

pub(super) fn parse(text: &str) -> Result<Parsed, String> {
    let map = extract_object(text, &FIELDS)?;
    let mut check = Check::default();
    check.fields(&map, "", &FIELDS);
    for field in ["visual_description", "thought_process", "command_response"] {
        check.string(&map, "", field);
    }
    if let Some(state) = map.get("verification_state")
        && let Some(state) = check.object(state, "verification_state", &STATE_FIELDS)
    {
        check.one_of(state, "verification_state", "phase", &PHASES);
        for field in &STATE_FIELDS[1..] {
            check.string(state, "verification_state", field);
        }
    }
    let command = map
        .get("command")
        .and_then(|command| check.object(command, "command", &AXIS_NAMES))
        .map(|command| AXIS_NAMES.map(|axis| check.integer(command, "command", axis)));
    let done = check.boolean(&map, "", "done");
    check.finish()?;
    let (Some([Some(a), Some(b), Some(c), Some(d)]), Some(done)) = (command, done) else {
        return Err("the command or done flag could not be read".into());
    };
    Ok(Parsed {
        action: Action::Michelson {
            command: [a, b, c, d],
            done,
        },
        claims: Value::Object(map),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(command: &str, done: &str) -> String {
        format!(
            r#"{{"visual_description": "two spots", "thought_process": "probe m1",
              "command_response": "unknown",
              "verification_state": {{"phase": "identify", "mirror_1_beam": "left",
                "mirror_2_beam": "unknown", "next_test": "move m1 axis 1"}},
              "command": {command}, "done": {done}}}"#
        )
    }

    #[test]
    fn a_valid_reply_becomes_an_absolute_command() {
        let text = reply(
            r#"{"mirror_1_axis_1": 1000, "mirror_1_axis_2": -20, "mirror_2_axis_1": 0, "mirror_2_axis_2": 5}"#,
            "false",
        );
        let parsed = parse(&format!("```json\n{text}\n```")).unwrap();
        assert_eq!(
            parsed.action,
            Action::Michelson {
                command: [1000, -20, 0, 5],
                done: false
            }
        );
        assert_eq!(parsed.claims["verification_state"]["phase"], "identify");
    }

    #[test]
    fn missing_axes_bad_types_and_bad_phase_are_all_named() {
        let text = reply(
            r#"{"mirror_1_axis_1": "100", "mirror_1_axis_2": 0, "mirror_2_axis_1": 0}"#,
            "1",
        )
        .replace("\"identify\"", "\"calibrate\"");
        let error = parse(&text).unwrap_err();
        for expected in [
            "`command.mirror_1_axis_1` must be a whole number",
            "`command.mirror_2_axis_2` is missing",
            "`done` must be true or false, got 1",
            "`verification_state.phase` must be one of search, identify",
        ] {
            assert!(error.contains(expected), "{expected:?} not in {error}");
        }
    }
}
