//! The relay reply: one action per turn, a relative tilt of one mirror, a camera move, or
//! done, each with a reason.

use optalign_optics::Station;
use serde_json::Value;

use super::{Check, Parsed, extract_object};
use crate::task::{Action, RelayAction};

const ACTIONS: [&str; 3] = ["tilt", "measure", "done"];
const MIRRORS: [&str; 4] = ["M1", "M2", "M3", "M4"];
const STATIONS: [&str; 8] = ["C1", "C2", "C3", "C4", "C5", "C6", "C7", "C8"];

pub(super) fn parse(text: &str) -> Result<Parsed, String> {
    let map = extract_object(text, &["action"])?;
    let mut check = Check::default();
    let Some(kind) = map.get("action").and_then(Value::as_str) else {
        return Err(format!(
            "`action` must be one of {}, got {}",
            ACTIONS.join(", "),
            map.get("action").map_or("nothing".into(), Value::to_string)
        ));
    };
    let action = match kind {
        "tilt" => {
            check.fields(
                &map,
                "",
                &["action", "mirror", "vertical", "horizontal", "reason"],
            );
            let mirror = check
                .one_of(&map, "", "mirror", &MIRRORS)
                .and_then(|m| MIRRORS.iter().position(|name| *name == m));
            let vertical = check.integer(&map, "", "vertical");
            let horizontal = check.integer(&map, "", "horizontal");
            match (mirror, vertical, horizontal) {
                (Some(mirror), Some(vertical), Some(horizontal)) => Some(RelayAction::Tilt {
                    mirror: mirror as u8,
                    vertical,
                    horizontal,
                }),
                _ => None,
            }
        }
        "measure" => {
            check.fields(&map, "", &["action", "station", "reason"]);
            check
                .one_of(&map, "", "station", &STATIONS)
                .and_then(|name| name.parse::<Station>().ok())
                .map(|station| RelayAction::Measure { station })
        }
        "done" => {
            check.fields(&map, "", &["action", "reason"]);
            Some(RelayAction::Done)
        }
        other => {
            return Err(format!(
                "`action` must be one of {}, got {other:?}",
                ACTIONS.join(", ")
            ));
        }
    };
    check.string(&map, "", "reason");
    check.finish()?;
    let Some(action) = action else {
        return Err("the action could not be read".into());
    };
    Ok(Parsed {
        action: Action::Relay(action),
        claims: Value::Object(map),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_action_shape_parses() {
        let tilt = parse(
            r#"{"action":"tilt","mirror":"M3","vertical":-2000,"horizontal":0,"reason":"probe"}"#,
        )
        .unwrap();
        assert_eq!(
            tilt.action,
            Action::Relay(RelayAction::Tilt {
                mirror: 2,
                vertical: -2000,
                horizontal: 0
            })
        );
        let measure = parse("Moving upstream.\n{\"action\":\"measure\",\"station\":\"C1\",\"reason\":\"dark at C8\"}")
            .unwrap();
        assert_eq!(
            measure.action,
            Action::Relay(RelayAction::Measure {
                station: Station::C1
            })
        );
        let done = parse(r#"{"action":"done","reason":"centred spot at C8"}"#).unwrap();
        assert_eq!(done.action, Action::Relay(RelayAction::Done));
        assert_eq!(done.claims["reason"], "centred spot at C8");
    }

    #[test]
    fn wrong_shapes_are_named() {
        let error =
            parse(r#"{"action":"tilt","mirror":"M5","vertical":1,"reason":"x","station":"C1"}"#)
                .unwrap_err();
        for expected in [
            "`mirror` must be one of M1, M2, M3, M4, got \"M5\"",
            "`horizontal` is missing",
            "`station` is not a field of the reply",
        ] {
            assert!(error.contains(expected), "{expected:?} not in {error}");
        }
        assert!(
            parse(r#"{"action":"jump","reason":"x"}"#)
                .unwrap_err()
                .contains("`action` must be one of tilt, measure, done, got \"jump\"")
        );
        assert!(
            parse(r#"{"action":"measure","station":"C9","reason":"x"}"#)
                .unwrap_err()
                .contains("`station` must be one of C1")
        );
        assert!(
            parse(r#"{"action":"done"}"#)
                .unwrap_err()
                .contains("`reason` is missing")
        );
    }
}
