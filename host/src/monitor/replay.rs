//! A finished run read back from its folder for `optalign monitor DIR`: `transcript.jsonl`
//! (every format this program has written: unknown line types are kept in the tail only)
//! and the saved frames in `frames/`. A partial last line, as a killed run leaves, is
//! skipped; a broken line before it is an error naming the line.

use std::path::Path;

use anyhow::{Context, bail};
use serde::Deserialize;
use serde_json::Value;

use super::frames::FrameStore;
use super::run::RunMonitor;
use super::steps::{record_step, start_step};
use super::view::{RunStatus, RunView};
use crate::rig::{ControllerView, Score};
use crate::run::{RunSummary, StepRecord};

/// The header line.
#[derive(Deserialize)]
struct Header {
    task: String,
    policy: String,
    seed: u64,
    budget: usize,
}

/// The start line.
#[derive(Deserialize)]
struct Start {
    image: Option<String>,
    score: Option<Score>,
}

/// A stop line (written since the monitor exists).
#[derive(Deserialize)]
struct Stop {
    #[serde(default)]
    controllers: Vec<ControllerView>,
}

/// Reads the run in `dir` into a monitor that shows it.
pub fn load_recorded(dir: &Path) -> anyhow::Result<RunMonitor> {
    let path = dir.join("transcript.jsonl");
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!(
            "cannot read {}: is {} a run folder?",
            path.display(),
            dir.display()
        )
    })?;
    let view = view_of_transcript(&text, &dir.display().to_string())
        .with_context(|| format!("in {}", path.display()))?;
    let frames_dir = dir.join("frames");
    let frames = if frames_dir.is_dir() {
        FrameStore::from_folder(frames_dir)
    } else {
        FrameStore::default()
    };
    let all_frames = frames.has_folder();
    Ok(RunMonitor::recorded(RunView { all_frames, ..view }, frames))
}

/// The view of a transcript's text.
pub fn view_of_transcript(text: &str, label: &str) -> anyhow::Result<RunView> {
    let mut view = RunView::new(label);
    view.status = RunStatus::Replay { outcome: None };
    let lines: Vec<&str> = text.lines().filter(|l| !l.trim().is_empty()).collect();
    let mut header_seen = false;
    for (index, line) in lines.iter().enumerate() {
        let value: Value = match serde_json::from_str(line) {
            Ok(value) => value,
            Err(_) if index + 1 == lines.len() => break,
            Err(error) => bail!("line {} is not JSON: {error}", index + 1),
        };
        view.push_tail(line);
        let kind = value
            .get("type")
            .and_then(Value::as_str)
            .unwrap_or("")
            .to_owned();
        let kind = kind.as_str();
        if kind == "run" {
            header_seen = true;
        }
        apply_line(&mut view, kind, value)
            .with_context(|| format!("line {} (a {kind:?} line)", index + 1))?;
    }
    anyhow::ensure!(header_seen, "the transcript has no run header line");
    Ok(view)
}

/// Adds one transcript line of type `kind` to the view; other types only reach the tail.
fn apply_line(view: &mut RunView, kind: &str, value: Value) -> anyhow::Result<()> {
    match kind {
        "run" => {
            let header: Header = serde_json::from_value(value)?;
            view.task = header.task;
            view.policy = header.policy;
            view.seed = header.seed;
            view.budget = header.budget;
        }
        "start" => {
            let start: Start = serde_json::from_value(value)?;
            let frame = start.image.map(|_| 0);
            view.steps.push(start_step(start.score.as_ref(), frame));
        }
        "step" => {
            let record: StepRecord = serde_json::from_value(value)?;
            let frame = match record.image {
                Some(_) => Some(record.evaluation),
                None => view.steps.last().and_then(|step| step.frame),
            };
            view.evaluations = view.evaluations.max(record.evaluation);
            view.steps.push(record_step(&record, frame));
        }
        "stop" => {
            let stop: Stop = serde_json::from_value(value)?;
            view.controllers = stop.controllers;
        }
        "end" => {
            let summary: RunSummary = serde_json::from_value(value)?;
            view.status = RunStatus::Replay {
                outcome: Some(outcome(&summary)),
            };
        }
        _ => {}
    }
    Ok(())
}

fn outcome(summary: &RunSummary) -> String {
    let verdict = if summary.success {
        "aligned"
    } else {
        "not aligned"
    };
    let error = summary
        .terminal_error
        .map_or("no light at C8".to_owned(), |e| format!("error {e:.1}"));
    match &summary.failure {
        Some(reason) => format!(
            "{verdict} after {} evaluations, {error} ({reason})",
            summary.evaluations_used
        ),
        None => format!(
            "{verdict} after {} evaluations, {error}",
            summary.evaluations_used
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::monitor::MarkKind;

    /// Written by optalign before the monitor existed (`run michelson --sim --policy
    /// vision --seed 1`); its frames are left out to keep the repository small.
    const RECORDED: &str = "src/monitor/testdata/recorded-michelson";

    #[test]
    fn a_run_recorded_before_the_monitor_reads_back_whole() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join(RECORDED);
        let monitor = load_recorded(&dir).unwrap();
        let view = monitor.subscribe().borrow().clone();
        assert_eq!(
            (
                view.task.as_str(),
                view.policy.as_str(),
                view.seed,
                view.budget
            ),
            ("michelson", "vision", 1, 60)
        );
        assert_eq!(view.steps.len(), 12, "the start and eleven steps");
        assert_eq!(view.evaluations, 11);
        assert_eq!(view.steps[0].frame, Some(0));
        assert_eq!(view.steps[11].frame, Some(11));
        assert_eq!(view.steps[0].action, None);
        assert!(
            view.steps[1]
                .action
                .as_deref()
                .unwrap()
                .starts_with("m1=(512, 0)")
        );
        let summary: RunSummary =
            serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap();
        assert_eq!(view.steps[11].error, summary.terminal_error);
        assert_eq!(
            view.status,
            RunStatus::Replay {
                outcome: Some("aligned after 11 evaluations, error 0.5".into())
            }
        );
        let believed = |step: usize| -> Vec<(String, f64, f64)> {
            view.steps[step]
                .marks
                .iter()
                .filter(|m| m.kind == MarkKind::Believed)
                .map(|m| (m.label.clone(), m.x.round(), m.y.round()))
                .collect()
        };
        assert_eq!(believed(5), [], "no beliefs while probing blind");
        assert_eq!(
            believed(10),
            [
                ("beam 1".into(), 757.0, 540.0),
                ("beam 2".into(), 1163.0, 540.0)
            ]
        );
        assert_eq!(
            view.steps[10].claims.as_ref().unwrap()["phase"],
            "check both beams apart near the centre"
        );
        assert!(!view.all_frames, "the fixture has no frames folder");
        assert_eq!(view.tail.len(), 14);
    }

    #[test]
    fn a_killed_run_loses_only_its_partial_last_line_and_a_broken_one_is_named() {
        let text = std::fs::read_to_string(
            Path::new(env!("CARGO_MANIFEST_DIR"))
                .join(RECORDED)
                .join("transcript.jsonl"),
        )
        .unwrap();
        let lines: Vec<&str> = text.lines().collect();
        let killed = format!("{}\n{}", lines[..5].join("\n"), &lines[5][..40]);
        let view = view_of_transcript(&killed, "killed").unwrap();
        assert_eq!(view.steps.len(), 4);
        assert_eq!(view.status, RunStatus::Replay { outcome: None });

        let broken = format!("{}\n{{oops\n{}", lines[..3].join("\n"), lines[3]);
        let error = format!("{:#}", view_of_transcript(&broken, "broken").unwrap_err());
        assert!(error.contains("line 4 is not JSON"), "{error}");

        let bad_step = format!(
            "{}\n{{\"type\":\"step\",\"evaluation\":\"two\"}}\n{}",
            lines[0], lines[1]
        );
        let error = format!("{:#}", view_of_transcript(&bad_step, "bad").unwrap_err());
        assert!(error.contains("line 2 (a \"step\" line)"), "{error}");

        let error = view_of_transcript(lines[1], "headless")
            .unwrap_err()
            .to_string();
        assert!(error.contains("no run header"), "{error}");
    }
}
