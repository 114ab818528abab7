//! What the monitor page shows of one run, as plain serialisable data: the run's header,
//! its steps (action, feedback, the policy's words, errors, overlay marks), the controllers,
//! the transcript's last lines and whether the run is running, paused or over. The live run
//! and the replay of a finished one fill the same view.

use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::rig::ControllerView;

/// How many transcript lines the view keeps.
pub const TAIL_LINES: usize = 40;

/// A transcript line is cut to this many characters in the tail (a VLM exchange can be
/// long; the file keeps it whole).
pub const TAIL_LINE_CHARS: usize = 400;

/// Where the run is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum RunStatus {
    /// Created, before the first frame.
    Starting,
    Running,
    /// Held before its next action until resumed.
    Paused,
    /// Over; `reason` says why when it ended early.
    Finished {
        success: bool,
        reason: Option<String>,
    },
    /// A recorded run shown again; `outcome` says how it ended (none when its transcript
    /// has no closing line: the run was killed).
    Replay {
        outcome: Option<String>,
    },
}

/// A point drawn on the frame, px (x right, y down) in the frame's own pixels.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Mark {
    pub kind: MarkKind,
    pub label: String,
    pub x: f64,
    pub y: f64,
    /// `x` and `y` are measured from the image centre rather than its corner.
    pub from_centre: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MarkKind {
    /// The hidden truth (simulation only).
    True,
    /// Where the agent says it is.
    Believed,
}

/// One step as shown: the start (evaluation 0, no action) or one action.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StepView {
    /// Evaluations spent after this step.
    pub evaluation: usize,
    /// The action in words; `None` for the start.
    pub action: Option<String>,
    /// What came of the action: executed (with times) or why it was refused.
    pub feedback: String,
    pub rejected: bool,
    /// The frame shown after this step, as its evaluation number (a refused action shows
    /// the unchanged frame of the step before).
    pub frame: Option<usize>,
    pub error: Option<f64>,
    pub best_error: Option<f64>,
    /// The model's own words (VLM).
    pub text: Option<String>,
    /// What the agent claims (the vision agent's beliefs, the VLM's structured reply).
    pub claims: Option<Value>,
    pub marks: Vec<Mark>,
}

/// The whole view of one run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunView {
    pub label: String,
    pub task: String,
    pub policy: String,
    pub seed: u64,
    pub budget: usize,
    pub evaluations: usize,
    pub status: RunStatus,
    pub steps: Vec<StepView>,
    pub controllers: Vec<ControllerView>,
    /// The transcript's last lines, oldest first.
    pub tail: Vec<String>,
    /// Frames can be fetched for every step (a recorded run with saved frames), not only
    /// the newest.
    pub all_frames: bool,
}

impl RunView {
    pub fn new(label: &str) -> Self {
        Self {
            label: label.to_owned(),
            task: String::new(),
            policy: String::new(),
            seed: 0,
            budget: 0,
            evaluations: 0,
            status: RunStatus::Starting,
            steps: Vec::new(),
            controllers: Vec::new(),
            tail: Vec::new(),
            all_frames: false,
        }
    }

    /// Appends a transcript line to the tail, cut to `TAIL_LINE_CHARS`, keeping the
    /// last `TAIL_LINES`.
    pub fn push_tail(&mut self, line: &str) {
        let cut: String = match line.char_indices().nth(TAIL_LINE_CHARS) {
            Some((end, _)) => format!("{} …", &line[..end]),
            None => line.to_owned(),
        };
        self.tail.push(cut);
        if self.tail.len() > TAIL_LINES {
            let extra = self.tail.len() - TAIL_LINES;
            self.tail.drain(..extra);
        }
    }

    /// What a page that has the first `known` steps needs next: the newer steps and
    /// everything else.
    pub fn update_since(&self, known: usize) -> Value {
        let from = known.min(self.steps.len());
        serde_json::json!({
            "label": self.label,
            "task": self.task,
            "policy": self.policy,
            "seed": self.seed,
            "budget": self.budget,
            "evaluations": self.evaluations,
            "status": self.status,
            "controllers": self.controllers,
            "tail": self.tail,
            "all_frames": self.all_frames,
            "from": from,
            "steps": &self.steps[from..],
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_tail_keeps_the_last_lines_and_cuts_long_ones() {
        let mut view = RunView::new("run");
        for n in 0..TAIL_LINES + 5 {
            view.push_tail(&format!("line {n}"));
        }
        assert_eq!(view.tail.len(), TAIL_LINES);
        assert_eq!(view.tail[0], "line 5");
        view.push_tail(&"é".repeat(TAIL_LINE_CHARS + 10));
        let last = view.tail.last().unwrap();
        assert_eq!(last.chars().count(), TAIL_LINE_CHARS + 2);
        assert!(last.ends_with(" …"));
    }

    #[test]
    fn an_update_carries_only_the_steps_the_page_lacks() {
        let mut view = RunView::new("run");
        for evaluation in 0..3 {
            view.steps.push(StepView {
                evaluation,
                action: None,
                feedback: String::new(),
                rejected: false,
                frame: Some(evaluation),
                error: None,
                best_error: None,
                text: None,
                claims: None,
                marks: Vec::new(),
            });
        }
        let update = view.update_since(2);
        assert_eq!(update["from"], 2);
        assert_eq!(update["steps"].as_array().unwrap().len(), 1);
        assert_eq!(update["steps"][0]["evaluation"], 2);
        assert_eq!(view.update_since(9)["steps"].as_array().unwrap().len(), 0);
    }
}
