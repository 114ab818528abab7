//! The run transcript: `transcript.jsonl` with one line per event, flushed as it is
//! written, frames as PNG files beside it, and `summary.json` at the end. A killed run
//! leaves every line written so far readable.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::Context;
use optalign_optics::Frame;
use serde::{Deserialize, Serialize};
use serde_json::json;

use super::summary::{Failure, RunSummary};
use crate::monitor::RunMonitor;
use crate::policy::Decision;
use crate::rig::{ControllerView, Executed, Score};
use crate::task::{Action, TaskKind};

/// The file a finished run's summary is written to, in its folder.
pub const SUMMARY_FILE: &str = "summary.json";

/// One evaluation, or one rejected action, as recorded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    /// Evaluations spent after this step (a rejected action spends none).
    pub evaluation: usize,
    pub action: Action,
    /// Why the action was refused (nothing moved); `None` when it ran.
    pub rejected: Option<String>,
    /// The frame after the action, relative to the run folder.
    pub image: Option<String>,
    /// The hidden-truth score after the action (not for policies).
    pub score: Option<Score>,
    pub error: Option<f64>,
    pub best_error: Option<f64>,
    pub motor_time_s: f64,
    pub camera_time_s: f64,
    pub agent_latency_s: f64,
    /// What the agent claimed, for analysis next to the truth.
    pub claims: Option<serde_json::Value>,
}

impl StepRecord {
    pub fn rejected(evaluation: usize, decision: &Decision, reason: &str) -> Self {
        Self {
            evaluation,
            action: decision.action.clone(),
            rejected: Some(reason.to_owned()),
            image: None,
            score: None,
            error: None,
            best_error: None,
            motor_time_s: 0.0,
            camera_time_s: 0.0,
            agent_latency_s: decision.latency_s,
            claims: decision.claims.clone(),
        }
    }

    pub fn executed(
        evaluation: usize,
        decision: &Decision,
        executed: &Executed,
        score: Score,
        best_error: Option<f64>,
        image: Option<&Path>,
    ) -> Self {
        Self {
            evaluation,
            action: decision.action.clone(),
            rejected: None,
            image: image
                .and_then(|p| p.file_name())
                .map(|name| format!("frames/{}", name.to_string_lossy())),
            score: Some(score),
            error: score.error(),
            best_error,
            motor_time_s: executed.motor_time_s,
            camera_time_s: executed.camera_time_s,
            agent_latency_s: decision.latency_s,
            claims: decision.claims.clone(),
        }
    }
}

/// An open transcript.
pub struct Transcript {
    dir: PathBuf,
    lines: BufWriter<File>,
    /// Sees every line as it is written (the live monitor's tail).
    observer: Option<RunMonitor>,
}

impl Transcript {
    /// Creates the run folder and starts `transcript.jsonl` with a header line.
    pub fn create(
        dir: &Path,
        task: TaskKind,
        policy: &str,
        seed: u64,
        budget: usize,
        observer: Option<RunMonitor>,
    ) -> anyhow::Result<Self> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create run folder {}", dir.display()))?;
        let path = dir.join("transcript.jsonl");
        let file =
            File::create(&path).with_context(|| format!("cannot create {}", path.display()))?;
        let mut transcript = Self {
            dir: dir.to_owned(),
            lines: BufWriter::new(file),
            observer,
        };
        transcript.line(&json!({
            "type": "run",
            "task": task,
            "policy": policy,
            "seed": seed,
            "budget": budget,
            "optalign": env!("CARGO_PKG_VERSION"),
        }))?;
        Ok(transcript)
    }

    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// The state before any action.
    pub fn start_state(&mut self, score: &Score, image: Option<&Path>) -> anyhow::Result<()> {
        let image = image
            .and_then(|p| p.file_name())
            .map(|n| format!("frames/{}", n.to_string_lossy()));
        self.line(
            &json!({ "type": "start", "image": image, "score": score, "error": score.error() }),
        )
    }

    pub fn append(&mut self, record: &StepRecord) -> anyhow::Result<()> {
        let mut value = serde_json::to_value(record)?;
        if let Some(object) = value.as_object_mut() {
            object.insert("type".into(), "step".into());
        }
        self.line(&value)
    }

    /// The operator paused the run: it is held before its next action.
    pub fn pause(&mut self, evaluation: usize) -> anyhow::Result<()> {
        self.line(&json!({ "type": "pause", "evaluation": evaluation }))
    }

    /// The operator let a paused run go on after `held_s` seconds: for good, or for
    /// `single_step` one action.
    pub fn resume(
        &mut self,
        evaluation: usize,
        held_s: f64,
        single_step: bool,
    ) -> anyhow::Result<()> {
        self.line(&json!({
            "type": "resume",
            "evaluation": evaluation,
            "held_s": held_s,
            "single_step": single_step,
        }))
    }

    /// The operator stopped the run: the emergency stop sent to every controller, what
    /// became of it, and the controllers' state as they report it afterwards.
    pub fn stop(
        &mut self,
        evaluation: usize,
        reason: &str,
        emergency_stop_error: Option<&str>,
        controllers: &[ControllerView],
    ) -> anyhow::Result<()> {
        self.line(&json!({
            "type": "stop",
            "evaluation": evaluation,
            "reason": reason,
            "emergency_stop_error": emergency_stop_error,
            "controllers": controllers,
        }))
    }

    /// The run failed at `evaluation`: what failed, why, and what the failing part had
    /// done before it gave up (a model's unusable replies, say).
    pub fn failure(
        &mut self,
        evaluation: usize,
        failure: &Failure,
        record: Option<serde_json::Value>,
    ) -> anyhow::Result<()> {
        self.line(&json!({
            "type": "failure",
            "evaluation": evaluation,
            "by": failure.by,
            "reason": failure.reason,
            "record": record,
        }))
    }

    /// Writes the closing line and `summary.json`.
    pub fn finish(&mut self, summary: &RunSummary) -> anyhow::Result<()> {
        let mut value = serde_json::to_value(summary)?;
        if let Some(object) = value.as_object_mut() {
            object.insert("type".into(), "end".into());
        }
        self.line(&value)?;
        let path = self.dir.join(SUMMARY_FILE);
        std::fs::write(&path, serde_json::to_vec_pretty(summary)?)
            .with_context(|| format!("cannot write {}", path.display()))
    }

    /// Saves a frame as `frames/NNNN.png` (the folder made with the first); returns its path.
    pub fn save_frame(&mut self, evaluation: usize, frame: &Frame) -> anyhow::Result<PathBuf> {
        let frames = self.dir.join("frames");
        std::fs::create_dir_all(&frames)
            .with_context(|| format!("cannot create {}", frames.display()))?;
        let path = frames.join(format!("{evaluation:04}.png"));
        let png = frame.encode_png()?;
        std::fs::write(&path, png).with_context(|| format!("cannot write {}", path.display()))?;
        Ok(path)
    }

    fn line(&mut self, value: &serde_json::Value) -> anyhow::Result<()> {
        serde_json::to_writer(&mut self.lines, value)?;
        self.lines.write_all(b"\n")?;
        self.lines.flush().context("cannot write the transcript")?;
        if let Some(observer) = &self.observer {
            observer.transcript_line(&value.to_string());
        }
        Ok(())
    }
}
