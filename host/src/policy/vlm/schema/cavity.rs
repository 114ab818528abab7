//! The cavity reply: per-image observations of the secondary beam, a strategy summary, and
//! either exactly one probe command (not done) or one final command (done).

use serde_json::{Map, Value};

use super::{Check, Parsed, extract_object};
use crate::task::Action;

const FIELDS: [&str; 6] = [
    "visual_description",
    "image_observations",
    "strategy_summary",
    "done",
    "probe_commands",
    "final_command",
];

const OBSERVATION_FIELDS: [&str; 7] = [
    "image_index",
    "command",
    "visibility",
    "x",
    "y",
    "confidence",
    "evidence",
];

/// How the agent may classify the secondary beam in an image.
pub const VISIBILITY: [&str; 4] = ["visible", "overlapped_or_hidden", "offscreen", "unknown"];

/// The agent's confidence levels.
pub const CONFIDENCE: [&str; 3] = ["low", "medium", "high"];

/// Probe commands per reply while not done (one image per batch).
pub const PROBES_PER_BATCH: usize = 1;

fn command(check: &mut Check, value: &Value, path: &str) -> Option<[i32; 2]> {
    let map = check.object(value, path, &["x", "y"])?;
    match (check.integer(map, path, "x"), check.integer(map, path, "y")) {
        (Some(x), Some(y)) => Some([x, y]),
        _ => None,
    }
}

fn observation(check: &mut Check, value: &Value, path: &str) {
    let Some(map) = check.object(value, path, &OBSERVATION_FIELDS) else {
        return;
    };
    if let Some(index) = map.get("image_index")
        && index.as_u64().is_none()
    {
        check.problem(format!(
            "`{path}.image_index` must be a whole number >= 0 (the number in the image's label), got {index}"
        ));
    }
    if let Some(value) = map.get("command") {
        command(check, value, &format!("{path}.command"));
    }
    let visibility = check.one_of(map, path, "visibility", &VISIBILITY);
    let x = check.number_or_null(map, path, "x");
    let y = check.number_or_null(map, path, "y");
    if let (Some(visibility), Some(x), Some(y)) = (visibility, x, y) {
        coordinates(check, path, visibility, [x, y]);
    }
    check.one_of(map, path, "confidence", &CONFIDENCE);
    check.string(map, path, "evidence");
}

/// Positions are numbers exactly when the beam is visible.
fn coordinates(check: &mut Check, path: &str, visibility: &str, xy: [Option<f64>; 2]) {
    for (name, value) in ["x", "y"].into_iter().zip(xy) {
        match (visibility == "visible", value) {
            (true, None) => check.problem(format!(
                "`{path}.{name}` must be a number when visibility is \"visible\""
            )),
            (false, Some(_)) => check.problem(format!(
                "`{path}.{name}` must be null when visibility is \"{visibility}\""
            )),
            _ => {}
        }
    }
}

/// The command to execute, from done, probe_commands and final_command.
fn chosen_command(check: &mut Check, map: &Map<String, Value>, done: bool) -> Option<[i32; 2]> {
    let probes = check.array(map, "", "probe_commands")?;
    let final_command = map.get("final_command")?;
    if done {
        if !probes.is_empty() {
            check.problem(format!(
                "`probe_commands` must be an empty list when done is true, got {} command(s)",
                probes.len()
            ));
        }
        if final_command.is_null() {
            check.problem("`final_command` must be one {\"x\": int, \"y\": int} command when done is true, got null".into());
            return None;
        }
        command(check, final_command, "final_command")
    } else {
        if !final_command.is_null() {
            check.problem("`final_command` must be null while done is false".into());
        }
        if probes.len() != PROBES_PER_BATCH {
            check.problem(format!(
                "`probe_commands` must hold exactly {PROBES_PER_BATCH} command while done is false, got {}",
                probes.len()
            ));
            return None;
        }
        command(check, &probes[0], "probe_commands[0]")
    }
}

pub(super) fn parse(text: &str) -> Result<Parsed, String> {
    let map = extract_object(text, &FIELDS)?;
    let mut check = Check::default();
    check.fields(&map, "", &FIELDS);
    check.string(&map, "", "visual_description");
    check.string(&map, "", "strategy_summary");
    if let Some(observations) = check.array(&map, "", "image_observations") {
        if observations.is_empty() {
            check.problem("`image_observations` must describe at least the newest image".into());
        }
        for (i, value) in observations.iter().enumerate() {
            observation(&mut check, value, &format!("image_observations[{i}]"));
        }
    }
    let done = check.boolean(&map, "", "done");
    let command = done.and_then(|done| chosen_command(&mut check, &map, done));
    check.finish()?;
    let (Some(done), Some(command)) = (done, command) else {
        return Err("the command to execute could not be read".into());
    };
    Ok(Parsed {
        action: Action::Cavity { command, done },
        claims: Value::Object(map),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reply(observation: &str, done: bool, probes: &str, final_command: &str) -> String {
        format!(
            r#"{{"visual_description": "primary centre, dim spot upper left",
              "image_observations": [{observation}],
              "strategy_summary": "x slope unknown", "done": {done},
              "probe_commands": {probes}, "final_command": {final_command}}}"#
        )
    }

    const SEEN: &str = r#"{"image_index": 2, "command": {"x": 0, "y": 0}, "visibility": "visible",
        "x": -0.3, "y": 0.2, "confidence": "medium", "evidence": "moved with x"}"#;

    #[test]
    fn a_probe_or_a_final_command_becomes_the_action() {
        let parsed = parse(&reply(SEEN, false, r#"[{"x": -2000, "y": 100}]"#, "null")).unwrap();
        assert_eq!(
            parsed.action,
            Action::Cavity {
                command: [-2000, 100],
                done: false
            }
        );
        assert_eq!(parsed.claims["image_observations"][0]["x"], -0.3);
        let parsed = parse(&reply(SEEN, true, "[]", r#"{"x": 1500, "y": -300}"#)).unwrap();
        assert_eq!(
            parsed.action,
            Action::Cavity {
                command: [1500, -300],
                done: true
            }
        );
    }

    #[test]
    fn malformed_probe_lists_are_explained() {
        let two = r#"[{"x": 1, "y": 2}, {"x": 3, "y": 4}]"#;
        assert!(
            parse(&reply(SEEN, false, two, "null"))
                .unwrap_err()
                .contains(
                    "`probe_commands` must hold exactly 1 command while done is false, got 2"
                )
        );
        let error = parse(&reply(SEEN, true, r#"[{"x": 1, "y": 2}]"#, "null")).unwrap_err();
        assert!(
            error.contains("must be an empty list when done is true"),
            "{error}"
        );
        assert!(error.contains("`final_command` must be one"), "{error}");
        let error = parse(&reply(SEEN, false, r#"[{"x": 1}]"#, r#"{"x": 0, "y": 0}"#)).unwrap_err();
        assert!(
            error.contains("`probe_commands[0].y` is missing"),
            "{error}"
        );
        assert!(error.contains("`final_command` must be null"), "{error}");
    }

    #[test]
    fn observations_must_match_their_visibility() {
        let hidden_with_position = SEEN.replace("\"visible\"", "\"offscreen\"");
        let error = parse(&reply(
            &hidden_with_position,
            false,
            r#"[{"x": 0, "y": 0}]"#,
            "null",
        ))
        .unwrap_err();
        assert!(
            error.contains(
                "`image_observations[0].x` must be null when visibility is \"offscreen\""
            ),
            "{error}"
        );
        let bad = SEEN
            .replace("\"medium\"", "\"sure\"")
            .replace("\"image_index\": 2", "\"image_index\": -1");
        let error = parse(&reply(&bad, false, r#"[{"x": 0, "y": 0}]"#, "null")).unwrap_err();
        assert!(
            error.contains("confidence` must be one of low, medium, high"),
            "{error}"
        );
        assert!(
            error.contains("image_index` must be a whole number >= 0"),
            "{error}"
        );
        let error = parse(&reply("", false, r#"[{"x": 0, "y": 0}]"#, "null")).unwrap_err();
        assert!(error.contains("at least the newest image"), "{error}");
    }
}
