//! System prompts: one text template per task (`host/prompts/*.txt`, built in, or a file
//! given with `--prompt`). Bounds and budgets are never written into a template: it names
//! them as `{{placeholder}}` and they are filled from the run's
//! [`TaskLimits`](crate::task::TaskLimits), so a scenario that changes a range changes the
//! prompt with it. What is known of the bench's geometry (from the rig file or the
//! scenario, through the brief) fills `{{bench}}`. An unknown placeholder is an error.

use std::path::Path;

use anyhow::Context;

use crate::policy::TaskBrief;
use crate::task::michelson::AXIS_NAMES as MICHELSON_AXES;
use crate::task::{BenchGeometry, TaskKind};

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

/// Every placeholder a template may use, with its value for the brief's task, limits and
/// bench.
pub fn placeholders(brief: &TaskBrief) -> Vec<(String, String)> {
    let limits = &brief.limits;
    let mut values = vec![
        ("budget".to_owned(), limits.budget(brief.task).to_string()),
        ("bench".to_owned(), describe_bench(&brief.geometry)),
    ];
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

/// The bench as the model reads it: one sentence per known value, or a note that the scales
/// are to be learned from the images when nothing is known.
pub fn describe_bench(geometry: &BenchGeometry) -> String {
    let mut lines = Vec::new();
    if let Some([long, short]) = geometry.relay_sides_mm {
        lines.push(format!(
            "The mirrors sit near the corners of a rectangle of about {long:.0} mm by {short:.0} mm."
        ));
    }
    if let Some(diameter) = geometry.mirror_diameter_mm {
        lines.push(format!(
            "Each mirror is a round mirror {diameter:.1} mm across."
        ));
    }
    if let Some(distances) = geometry.station_distances_mm {
        let list = distances
            .iter()
            .enumerate()
            .map(|(i, d)| format!("C{} {d:.0} mm", i + 1))
            .collect::<Vec<_>>()
            .join(", ");
        lines.push(format!(
            "Each camera station's distance from the mirror that starts its segment: {list}."
        ));
    }
    if let Some(spread) = geometry.placement_repeatability_mm {
        lines.push(format!(
            "Each time the camera is moved to a station it lands within about {spread:.2} mm (one standard deviation) of the same place, so a beam's position in the image shifts by that much from one visit to the next."
        ));
    }
    match (geometry.image_px, geometry.sensor_mm) {
        (Some([w, h]), Some([sw, sh])) => lines.push(format!(
            "The camera takes {w} x {h} pixel images of a {sw:.2} mm x {sh:.2} mm sensor ({:.1} micrometres per pixel).",
            1000.0 * sw / f64::from(w)
        )),
        (Some([w, h]), None) => lines.push(format!("The camera takes {w} x {h} pixel images.")),
        (None, Some([sw, sh])) => {
            lines.push(format!("The camera sensor is {sw:.2} mm x {sh:.2} mm."))
        }
        (None, None) => {}
    }
    if let Some(tilt) = geometry.tilt_rad_per_step {
        lines.push(format!(
            "The mounts' datasheet gives about {tilt:.2e} rad of tilt per motor step; the real response differs, so measure it from the images."
        ));
    }
    if lines.is_empty() {
        "Nothing about this bench's dimensions is known in advance: learn its scales from the images.".to_owned()
    } else {
        lines.join(" ")
    }
}

/// Fills a template's `{{name}}` placeholders; the error names an unknown or unclosed one.
pub fn render(template: &str, brief: &TaskBrief) -> Result<String, String> {
    let values = placeholders(brief);
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

/// The system prompt for a run: the built-in template or `file`, rendered for `brief`.
pub fn system_prompt(brief: &TaskBrief, file: Option<&Path>) -> anyhow::Result<String> {
    match file {
        Some(path) => {
            let template = std::fs::read_to_string(path)
                .with_context(|| format!("cannot read prompt {}", path.display()))?;
            render(&template, brief).map_err(|e| anyhow::anyhow!("prompt {}: {e}", path.display()))
        }
        None => render(builtin(brief.task), brief).map_err(anyhow::Error::msg),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::task::{Range, TaskLimits};

    fn brief(task: TaskKind, limits: &TaskLimits) -> TaskBrief {
        TaskBrief::new(task, limits, BenchGeometry::default())
    }

    #[test]
    fn built_in_prompts_take_their_bounds_from_the_limits() {
        let mut limits = TaskLimits::default();
        limits.michelson.ranges[1] = Range::symmetric(5000);
        limits.cavity.budget = 33;
        limits.relay.max_step = 12_345;
        for task in TaskKind::ALL {
            let prompt = system_prompt(&brief(task, &limits), None).unwrap();
            assert!(!prompt.contains("{{"), "{task}: unfilled placeholder");
            assert!(prompt.contains(&limits.budget(task).to_string()));
        }
        let michelson = system_prompt(&brief(TaskKind::Michelson, &limits), None).unwrap();
        assert!(michelson.contains("mirror_1_axis_2: [-5000, 5000]"));
        assert!(michelson.contains("mirror_2_axis_1: [-8192, 8192]"));
        let cavity = system_prompt(&brief(TaskKind::Cavity, &limits), None).unwrap();
        assert!(cavity.contains("allowed [-8000, 8000]"));
        assert!(cavity.contains("You have 33 images"));
        let relay = system_prompt(&brief(TaskKind::Relay, &limits), None).unwrap();
        assert!(relay.contains("within [-12345, 12345]"));
        assert!(relay.contains("within [-30000, 30000]"));
    }

    #[test]
    fn unknown_or_unclosed_placeholders_are_errors() {
        let limits = TaskLimits::default();
        let error = render("range {{x_rnage}}", &brief(TaskKind::Cavity, &limits)).unwrap_err();
        assert!(error.contains("unknown placeholder {{x_rnage}}"), "{error}");
        assert!(error.contains("x_range"), "{error}");
        let error = render("budget {{budget", &brief(TaskKind::Cavity, &limits)).unwrap_err();
        assert!(error.contains("never closed"), "{error}");
        assert_eq!(
            render(
                "{ \"x\": 1 } in {{ budget }} turns",
                &brief(TaskKind::Relay, &limits)
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
            system_prompt(&brief(TaskKind::Michelson, &limits), Some(&path)).unwrap(),
            "Budget 60."
        );
        let error = system_prompt(
            &brief(TaskKind::Michelson, &limits),
            Some(&dir.path().join("no")),
        )
        .unwrap_err();
        assert!(format!("{error:#}").contains("cannot read prompt"));
    }

    #[test]
    fn the_bench_geometry_of_the_brief_reaches_every_prompt() {
        let limits = TaskLimits::default();
        let geometry = BenchGeometry {
            sensor_mm: Some([5.76, 4.29]),
            image_px: Some([1280, 720]),
            tilt_rad_per_step: Some(3.3e-6),
            relay_sides_mm: Some([300.0, 200.0]),
            mirror_diameter_mm: Some(12.7),
            station_distances_mm: Some([20.0, 280.0, 20.0, 180.0, 20.0, 280.0, 20.0, 400.0]),
            placement_repeatability_mm: Some(0.25),
        };
        let relay = system_prompt(
            &TaskBrief::new(TaskKind::Relay, &limits, geometry.clone()),
            None,
        )
        .unwrap();
        for expected in [
            "300 mm by 200 mm",
            "12.7 mm across",
            "C2 280 mm",
            "C8 400 mm",
            "1280 x 720 pixel",
            "4.5 micrometres per pixel",
            "3.30e-6 rad",
            "within about 0.25 mm",
        ] {
            assert!(relay.contains(expected), "missing {expected:?}");
        }
        for task in [TaskKind::Michelson, TaskKind::Cavity] {
            let only_camera = BenchGeometry {
                image_px: Some([1280, 720]),
                ..BenchGeometry::default()
            };
            let prompt = system_prompt(&TaskBrief::new(task, &limits, only_camera), None).unwrap();
            assert!(prompt.contains("1280 x 720 pixel images"), "{task}");
        }
        let unknown = system_prompt(&brief(TaskKind::Relay, &limits), None).unwrap();
        assert!(unknown.contains("learn its scales from the images"));
        assert!(!unknown.contains("inches"));
    }
}
