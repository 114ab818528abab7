//! Reading a model's reply: find the one JSON object in it (code fences and surrounding
//! prose are tolerated), then check it field by field against the task's schema. Checking
//! is strict (every field present, nothing extra, the right types) and collects every
//! problem, so one corrective message can name them all.

mod cavity;
mod michelson;
mod relay;

use serde_json::{Map, Value};

use crate::task::{Action, TaskKind};

/// A reply that passed its task's schema.
#[derive(Clone, Debug, PartialEq)]
pub struct Parsed {
    pub action: Action,
    /// The reply object itself: the agent's claims (descriptions, beam estimates,
    /// visibility, done), recorded for analysis and never used for scoring.
    pub claims: Value,
}

/// Parses a reply for `task`; the error says exactly what is wrong.
pub fn parse_reply(task: TaskKind, text: &str) -> Result<Parsed, String> {
    match task {
        TaskKind::Michelson => michelson::parse(text),
        TaskKind::Cavity => cavity::parse(text),
        TaskKind::Relay => relay::parse(text),
    }
}

/// The text inside the first fenced code block that holds a `{`, or the whole text.
fn unfenced(text: &str) -> &str {
    let mut rest = text;
    while let Some(open) = rest.find("```") {
        let after = &rest[open + 3..];
        let Some(close) = after.find("```") else {
            return text;
        };
        let block = &after[..close];
        // Skip the info string ("json") on the fence line.
        let body = block.find('\n').map_or(block, |n| &block[n + 1..]);
        if body.contains('{') {
            return body;
        }
        rest = &after[close + 3..];
    }
    text
}

/// Finds the reply's JSON object. `top_keys` are the schema's top-level fields: when the
/// text around the object is not clean JSON, only an object holding one of them counts
/// (so a nested fragment of a broken reply is never mistaken for the reply).
pub(crate) fn extract_object(text: &str, top_keys: &[&str]) -> Result<Map<String, Value>, String> {
    let text = unfenced(text);
    if text.trim().is_empty() {
        return Err("the reply was empty".into());
    }
    let (Some(first), Some(last)) = (text.find('{'), text.rfind('}')) else {
        return Err("the reply holds no JSON object".into());
    };
    if last < first {
        return Err("the reply holds no complete JSON object".into());
    }
    let outer_error = match serde_json::from_str::<Map<String, Value>>(&text[first..=last]) {
        Ok(map) => return Ok(map),
        Err(error) => error,
    };
    let mut found = Vec::new();
    let mut position = first;
    while let Some(offset) = text[position..].find('{') {
        let start = position + offset;
        let mut stream = serde_json::Deserializer::from_str(&text[start..]).into_iter::<Value>();
        match stream.next() {
            Some(Ok(Value::Object(map))) => {
                position = start + stream.byte_offset();
                if top_keys.iter().any(|key| map.contains_key(*key)) {
                    found.push(map);
                }
            }
            _ => position = start + 1,
        }
    }
    match found.len() {
        1 => Ok(found.pop().expect("one object")),
        0 => Err(format!("the JSON is malformed: {outer_error}")),
        n => Err(format!(
            "the reply holds {n} separate JSON objects; send exactly one"
        )),
    }
}

/// A short rendering of a value for error messages.
fn show(value: &Value) -> String {
    let text = value.to_string();
    if text.chars().count() > 40 {
        format!("{}...", text.chars().take(37).collect::<String>())
    } else {
        text
    }
}

fn join_path(path: &str, key: &str) -> String {
    if path.is_empty() {
        key.to_owned()
    } else {
        format!("{path}.{key}")
    }
}

/// Collects schema problems while reading a reply.
#[derive(Default)]
pub(crate) struct Check {
    problems: Vec<String>,
}

impl Check {
    pub(crate) fn problem(&mut self, text: String) {
        self.problems.push(text);
    }

    /// Checks that `value` (at `path`) is an object with exactly `fields`.
    pub(crate) fn object<'a>(
        &mut self,
        value: &'a Value,
        path: &str,
        fields: &[&str],
    ) -> Option<&'a Map<String, Value>> {
        let Some(map) = value.as_object() else {
            self.problem(format!("`{path}` must be an object, got {}", show(value)));
            return None;
        };
        self.fields(map, path, fields);
        Some(map)
    }

    /// Reports missing and unknown fields of `map`.
    pub(crate) fn fields(&mut self, map: &Map<String, Value>, path: &str, fields: &[&str]) {
        for field in fields {
            if !map.contains_key(*field) {
                self.problem(format!("`{}` is missing", join_path(path, field)));
            }
        }
        for key in map.keys() {
            if !fields.contains(&key.as_str()) {
                let place = if path.is_empty() {
                    "the reply".to_owned()
                } else {
                    format!("`{path}`")
                };
                self.problem(format!(
                    "`{}` is not a field of {place} (allowed: {})",
                    join_path(path, key),
                    fields.join(", ")
                ));
            }
        }
    }

    pub(crate) fn string<'a>(
        &mut self,
        map: &'a Map<String, Value>,
        path: &str,
        key: &str,
    ) -> Option<&'a str> {
        let value = map.get(key)?;
        let text = value.as_str();
        if text.is_none() {
            self.problem(format!(
                "`{}` must be a string, got {}",
                join_path(path, key),
                show(value)
            ));
        }
        text
    }

    /// A string that must be one of `allowed`.
    pub(crate) fn one_of<'a>(
        &mut self,
        map: &'a Map<String, Value>,
        path: &str,
        key: &str,
        allowed: &[&str],
    ) -> Option<&'a str> {
        let text = self.string(map, path, key)?;
        if allowed.contains(&text) {
            Some(text)
        } else {
            self.problem(format!(
                "`{}` must be one of {}, got {}",
                join_path(path, key),
                allowed.join(", "),
                show(&Value::from(text))
            ));
            None
        }
    }

    pub(crate) fn boolean(
        &mut self,
        map: &Map<String, Value>,
        path: &str,
        key: &str,
    ) -> Option<bool> {
        let value = map.get(key)?;
        let flag = value.as_bool();
        if flag.is_none() {
            self.problem(format!(
                "`{}` must be true or false, got {}",
                join_path(path, key),
                show(value)
            ));
        }
        flag
    }

    /// A whole number of motor steps that fits a setting.
    pub(crate) fn integer(
        &mut self,
        map: &Map<String, Value>,
        path: &str,
        key: &str,
    ) -> Option<i32> {
        let value = map.get(key)?;
        let name = join_path(path, key);
        match value.as_i64() {
            Some(n) => match i32::try_from(n) {
                Ok(n) => Some(n),
                Err(_) => {
                    self.problem(format!("`{name}` = {n} is far outside any motor range"));
                    None
                }
            },
            None => {
                self.problem(format!(
                    "`{name}` must be a whole number (an integer), got {}",
                    show(value)
                ));
                None
            }
        }
    }

    pub(crate) fn array<'a>(
        &mut self,
        map: &'a Map<String, Value>,
        path: &str,
        key: &str,
    ) -> Option<&'a Vec<Value>> {
        let value = map.get(key)?;
        let items = value.as_array();
        if items.is_none() {
            self.problem(format!(
                "`{}` must be a list, got {}",
                join_path(path, key),
                show(value)
            ));
        }
        items
    }

    /// A finite number or null.
    pub(crate) fn number_or_null(
        &mut self,
        map: &Map<String, Value>,
        path: &str,
        key: &str,
    ) -> Option<Option<f64>> {
        let value = map.get(key)?;
        match value {
            Value::Null => Some(None),
            Value::Number(n) => n.as_f64().map(Some),
            other => {
                self.problem(format!(
                    "`{}` must be a number or null, got {}",
                    join_path(path, key),
                    show(other)
                ));
                None
            }
        }
    }

    /// Ends the check: every problem in one message.
    pub(crate) fn finish(self) -> Result<(), String> {
        if self.problems.is_empty() {
            Ok(())
        } else {
            Err(self.problems.join("; "))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEYS: &[&str] = &["action", "done"];

    #[test]
    fn finds_the_object_in_fences_and_prose() {
        let fenced =
            "Here it is:\n```json\n{\"action\": \"done\", \"reason\": \"ok\"}\n```\nThanks.";
        assert_eq!(extract_object(fenced, KEYS).unwrap()["action"], "done");
        let prose = "I think {x} matters. {\"action\": \"done\"} That is all.";
        assert_eq!(extract_object(prose, KEYS).unwrap()["action"], "done");
        let nested = "{\"done\": false, \"command\": {\"x\": 1}}";
        assert_eq!(extract_object(nested, KEYS).unwrap()["command"]["x"], 1);
    }

    #[test]
    fn explains_what_is_wrong_with_the_json() {
        assert_eq!(
            extract_object("  ", KEYS).unwrap_err(),
            "the reply was empty"
        );
        assert!(
            extract_object("no json here", KEYS)
                .unwrap_err()
                .contains("no JSON object")
        );
        let broken = "{\"done\": false, \"command\": {\"x\": 1} \"reason\": 2}";
        let error = extract_object(broken, KEYS).unwrap_err();
        assert!(
            error.starts_with("the JSON is malformed: expected"),
            "{error}"
        );
        let two = "{\"action\": \"done\"} or maybe {\"action\": \"measure\"}";
        assert!(
            extract_object(two, KEYS)
                .unwrap_err()
                .contains("2 separate JSON objects")
        );
    }

    #[test]
    fn check_collects_every_problem_with_its_path() {
        let value: Value = serde_json::json!({
            "command": {"x": 1.5, "z": 0},
            "done": "yes",
            "extra": 1
        });
        let mut check = Check::default();
        let map = check
            .object(&value, "", &["command", "done", "reason"])
            .unwrap();
        check.boolean(map, "", "done");
        let command = check
            .object(&map["command"], "command", &["x", "y"])
            .unwrap();
        check.integer(command, "command", "x");
        let error = check.finish().unwrap_err();
        for expected in [
            "`reason` is missing",
            "`extra` is not a field of the reply",
            "`done` must be true or false, got \"yes\"",
            "`command.y` is missing",
            "`command.z` is not a field of `command`",
            "`command.x` must be a whole number (an integer), got 1.5",
        ] {
            assert!(error.contains(expected), "{expected:?} not in {error}");
        }
    }
}
