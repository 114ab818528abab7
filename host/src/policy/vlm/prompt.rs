//! System prompts: one text template per task (`host/prompts/*.txt`, built in, or a file
//! given with `--prompt`). Bounds and budgets are never written into a template: it names
//! them as `{{placeholder}}` and they are filled from the run's [`TaskLimits`], so a scenario
//! that changes a range changes the prompt with it. An unknown placeholder is an error.

use std::path::Path;

use anyhow::Context;

use crate::task::michelson::AXIS_NAMES as MICHELSON_AXES;
use crate::task::{TaskKind, TaskLimits};

const MICHELSON: &str = include_str!("../../../prompts/michelson.txt");
const CAVITY: &str = include_str!("../../../prompts/cavity.txt");
const RELAY: &str = include_str!("../../../prompts/relay.txt");

/// The built-in template of a task.
pub fn builtin(task: TaskKind) -> &'static str {
    match task {
        TaskKind::Michelson => MICHELSON,
        TaskKind::Cavity => CAVITY,
        TaskKind::Relay => RELAY,
    }
}

/// Every placeholder a template may use, with its value for `task` under `limits`.
pub fn placeholders(task: TaskKind, limits: &TaskLimits) -> Vec<(String, String)> {
    let mut values = vec![("budget".to_owned(), limits.budget(task).to_string())];
    for (name, range) in MICHELSON_AXES.iter().zip(limits.michelson.ranges) {
        values.push(((*name).to_owned(), range.to_string()));
    }
    values.push(("x_range".into(), limits.cavity.ranges[0].to_string()));
    values.push(("y_range".into(), limits.cavity.ranges[1].to_string()));
    values.push(("max_step".into(), limits.relay.max_step.to_string()));
    values.push((
        "max_cumulative".into(),
        limits.relay.max_cumulative.to_string(),
    ));
    values
}

/// Fills a template's `{{name}}` placeholders; the error names an unknown or unclosed one.
pub fn render(template: &str, task: TaskKind, limits: &TaskLimits) -> Result<String, String> {
    let values = placeholders(task, limits);
    let mut out = String::with_capacity(template.len());
    let mut rest = template;
    while let Some(open) = rest.find("{{") {
        out.push_str(&rest[..open]);
        let after = &rest[open + 2..];
        let close = after.find("}}").ok_or_else(|| {
            format!(
                "a `{{{{` placeholder is never closed: {:.30}",
                &rest[open..]
            )
        })?;
        let name = after[..close].trim();
        let value = values
            .iter()
            .find(|(key, _)| key == name)
            .map(|(_, value)| value)
            .ok_or_else(|| {
                format!(
                    "unknown placeholder {{{{{name}}}}}; known: {}",
                    values
                        .iter()
                        .map(|(key, _)| key.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?;
        out.push_str(value);
        rest = &after[close + 2..];
    }
    out.push_str(rest);
    Ok(out)
}

/// The system prompt for a run: the built-in template or `file`, rendered with `limits`.
pub fn system_prompt(
    task: TaskKind,
    limits: &TaskLimits,
    file: Option<&Path>,
) -> anyhow::Result<String> {
    match file {
        Some(path) => {
            let template = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read prompt {}", path.display()))?;
            render(&template, task, limits)
                .map_err(|e| anyhow::anyhow!("prompt {}: {e}", path.display()))
        }
        None => render(builtin(task), task, limits).map_err(anyhow::Error::msg),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::Range;

    #[test]
    fn built_in_prompts_take_their_bounds_from_the_limits() {
        let mut limits = TaskLimits::default();
        limits.michelson.ranges[1] = Range::symmetric(5000);
        limits.cavity.budget = 33;
        limits.relay.max_step = 12_345;
        for task in TaskKind::ALL {
            let prompt = system_prompt(task, &limits, None).unwrap();
            assert!(!prompt.contains("{{"), "{task}: unfilled placeholder");
            assert!(prompt.contains(&limits.budget(task).to_string()));
        }
        let michelson = system_prompt(TaskKind::Michelson, &limits, None).unwrap();
        assert!(michelson.contains("mirror_1_axis_2: [-5000, 5000]"));
        assert!(michelson.contains("mirror_2_axis_1: [-8192, 8192]"));
        let cavity = system_prompt(TaskKind::Cavity, &limits, None).unwrap();
        assert!(cavity.contains("allowed [-8000, 8000]"));
        assert!(cavity.contains("You have 33 images"));
        let relay = system_prompt(TaskKind::Relay, &limits, None).unwrap();
        assert!(relay.contains("within [-12345, 12345]"));
        assert!(relay.contains("within [-30000, 30000]"));
    }

    #[test]
    fn unknown_or_unclosed_placeholders_are_errors() {
        let limits = TaskLimits::default();
        let error = render("range {{x_rnage}}", TaskKind::Cavity, &limits).unwrap_err();
        assert!(error.contains("unknown placeholder {{x_rnage}}"), "{error}");
        assert!(error.contains("x_range"), "{error}");
        let error = render("budget {{budget", TaskKind::Cavity, &limits).unwrap_err();
        assert!(error.contains("never closed"), "{error}");
        assert_eq!(
            render(
                "{ \"x\": 1 } in {{ budget }} turns",
                TaskKind::Relay,
                &limits
            )
            .unwrap(),
            "{ \"x\": 1 } in 100 turns"
        );
    }

    #[test]
    fn a_prompt_file_overrides_the_built_in_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("p.txt");
        std::fs::write(&path, "Budget {{budget}}.").unwrap();
        let limits = TaskLimits::default();
        assert_eq!(
            system_prompt(TaskKind::Michelson, &limits, Some(&path)).unwrap(),
            "Budget 60."
        );
        let error =
            system_prompt(TaskKind::Michelson, &limits, Some(&dir.path().join("no"))).unwrap_err();
        assert!(format!("{error:#}").contains("cannot read prompt"));
    }
}
