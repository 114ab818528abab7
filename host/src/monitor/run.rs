//! [`RunMonitor`]: the link between one run and its page. The run loop hands it each step,
//! frame and transcript line and asks it, before every action, whether the operator paused
//! or stopped the run; the server reads the view and sends the operator's commands. Nothing
//! here blocks the run: the view sits in a watch channel (a page sees the latest state and
//! skips what it missed) and the frame is kept, not encoded.

use std::path::PathBuf;
use std::sync::Arc;

use optalign_optics::Frame;
use tokio::sync::watch;

use super::frames::FrameStore;
use super::steps::{record_step, start_step};
use super::view::{RunStatus, RunView, StepView};
use crate::rig::{ControllerView, Score};
use crate::run::{RunSummary, StepRecord};

/// What the operator asked of the run.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Control {
    pub paused: bool,
    /// Single actions the operator let through a paused run, not yet taken.
    pub steps: usize,
    /// Set once by the stop button, with the reason.
    pub stop: Option<String>,
}

/// Why an operator's command was refused.
#[derive(Debug, PartialEq, thiserror::Error)]
pub enum ControlError {
    #[error("this is a recorded run: there is nothing to pause or stop")]
    Recorded,
    #[error("the run is over")]
    Over,
}

/// A shared handle on one run's view and controls (cheap to clone).
#[derive(Clone)]
pub struct RunMonitor {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for RunMonitor {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RunMonitor")
            .field("label", &self.inner.view.borrow().label)
            .finish_non_exhaustive()
    }
}

struct Inner {
    view: watch::Sender<RunView>,
    control: watch::Sender<Control>,
    frames: FrameStore,
    recorded: bool,
}

impl RunMonitor {
    /// A monitor for a run about to start.
    pub fn new(label: &str) -> Self {
        Self::with(RunView::new(label), FrameStore::default(), false)
    }

    /// A monitor showing a finished run: its view and the folder of its saved frames.
    pub fn recorded(view: RunView, frames: FrameStore) -> Self {
        Self::with(view, frames, true)
    }

    fn with(view: RunView, frames: FrameStore, recorded: bool) -> Self {
        Self {
            inner: Arc::new(Inner {
                view: watch::Sender::new(view),
                control: watch::Sender::new(Control::default()),
                frames,
                recorded,
            }),
        }
    }

    // The run's side.

    /// The run's identity and budget; `frames` is where it saves its frames, if it does.
    pub fn begin(
        &self,
        task: &str,
        policy: &str,
        seed: u64,
        budget: usize,
        frames: Option<PathBuf>,
    ) {
        if let Some(folder) = frames {
            self.inner.frames.set_folder(folder);
        }
        let all_frames = self.inner.frames.has_folder();
        self.inner.view.send_modify(|view| {
            view.task = task.to_owned();
            view.policy = policy.to_owned();
            view.seed = seed;
            view.budget = budget;
            view.all_frames = all_frames;
        });
    }

    /// The first frame and its score.
    pub fn start(&self, frame: Arc<Frame>, score: &Score) {
        self.inner.frames.set_newest(0, frame);
        self.inner.view.send_modify(|view| {
            view.steps.push(start_step(Some(score), Some(0)));
            view.status = RunStatus::Running;
        });
    }

    /// One step; `frame` is the new frame for an executed action.
    pub fn step(&self, record: &StepRecord, frame: Option<Arc<Frame>>) {
        let shown = match frame {
            Some(frame) => {
                self.inner.frames.set_newest(record.evaluation, frame);
                Some(record.evaluation)
            }
            None => self
                .inner
                .view
                .borrow()
                .steps
                .last()
                .and_then(|step| step.frame),
        };
        self.inner.view.send_modify(|view| {
            view.steps.push(record_step(record, shown));
            view.evaluations = record.evaluation;
        });
    }

    /// A live view without a run (`optalign jog`): `frame` becomes the newest, shown by a
    /// step of its own that says what was done (`action`, none for a refresh) and what came
    /// of it.
    pub fn live(&self, frame: Arc<Frame>, action: Option<String>, feedback: String) {
        let number = self.inner.view.borrow().steps.len();
        self.inner.frames.set_newest(number, frame);
        self.inner.view.send_modify(|view| {
            view.steps.push(StepView {
                evaluation: number,
                action,
                feedback,
                rejected: false,
                frame: Some(number),
                error: None,
                best_error: None,
                text: None,
                claims: None,
                marks: Vec::new(),
            });
            view.evaluations = number;
            view.status = RunStatus::Running;
        });
    }

    pub fn set_controllers(&self, controllers: Vec<ControllerView>) {
        self.inner
            .view
            .send_modify(|view| view.controllers = controllers);
    }

    pub fn transcript_line(&self, line: &str) {
        self.inner.view.send_modify(|view| view.push_tail(line));
    }

    /// Shows the run as held (true) or going again (false).
    pub fn show_paused(&self, paused: bool) {
        self.inner.view.send_modify(|view| {
            view.status = if paused {
                RunStatus::Paused
            } else {
                RunStatus::Running
            };
        });
    }

    pub fn finish(&self, summary: &RunSummary) {
        self.inner.view.send_modify(|view| {
            view.status = RunStatus::Finished {
                success: summary.success,
                reason: summary.failure.clone(),
            };
        });
    }

    /// What the operator wants now.
    pub fn control(&self) -> Control {
        self.inner.control.borrow().clone()
    }

    /// Resolves with the reason once the operator stops the run.
    pub async fn stopped(&self) -> String {
        let mut control = self.inner.control.subscribe();
        match control.wait_for(|c| c.stop.is_some()).await {
            Ok(control) => control.stop.clone().unwrap_or_default(),
            // The sender lives as long as this handle: never reached.
            Err(_) => std::future::pending().await,
        }
    }

    /// Resolves when a paused run may go on: resumed, stopped, or let through for one
    /// action (true: that single action was taken from the operator's allowance).
    pub async fn released(&self) -> bool {
        let mut control = self.inner.control.subscribe();
        let _ = control
            .wait_for(|c| !c.paused || c.stop.is_some() || c.steps > 0)
            .await;
        let mut single = false;
        self.inner.control.send_modify(|c| {
            if c.paused && c.stop.is_none() && c.steps > 0 {
                c.steps -= 1;
                single = true;
            }
        });
        single
    }

    // The operator's side.

    pub fn subscribe(&self) -> watch::Receiver<RunView> {
        self.inner.view.subscribe()
    }

    pub fn frames(&self) -> &FrameStore {
        &self.inner.frames
    }

    pub fn is_over(&self) -> bool {
        matches!(
            self.inner.view.borrow().status,
            RunStatus::Finished { .. } | RunStatus::Replay { .. }
        )
    }

    /// Holds the run before its next action (true) or lets it go on (false).
    pub fn set_paused(&self, paused: bool) -> Result<(), ControlError> {
        self.check_live()?;
        self.inner.control.send_modify(|c| c.paused = paused);
        Ok(())
    }

    /// Lets a paused run take one more action, then hold again.
    pub fn allow_step(&self) -> Result<(), ControlError> {
        self.check_live()?;
        self.inner.control.send_modify(|c| c.steps += 1);
        Ok(())
    }

    /// Stops the run: the loop stops every controller at once and ends the run.
    pub fn request_stop(&self, reason: &str) -> Result<(), ControlError> {
        self.check_live()?;
        self.inner.control.send_modify(|c| {
            c.stop.get_or_insert_with(|| reason.to_owned());
        });
        Ok(())
    }

    fn check_live(&self) -> Result<(), ControlError> {
        if self.inner.recorded {
            return Err(ControlError::Recorded);
        }
        if self.is_over() {
            return Err(ControlError::Over);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::time::Duration;

    use super::*;

    #[tokio::test]
    async fn a_stop_releases_a_paused_run_and_keeps_its_first_reason() {
        let monitor = RunMonitor::new("run");
        monitor.set_paused(true).unwrap();
        assert!(monitor.control().paused);
        monitor.allow_step().unwrap();
        assert!(monitor.released().await, "one action is let through");
        assert_eq!(monitor.control().steps, 0);
        let held = tokio::spawn({
            let monitor = monitor.clone();
            async move { monitor.released().await }
        });
        tokio::time::sleep(Duration::from_millis(20)).await;
        assert!(!held.is_finished(), "a paused run is held");
        monitor.request_stop("first").unwrap();
        monitor.request_stop("second").unwrap();
        tokio::time::timeout(Duration::from_secs(2), held)
            .await
            .expect("a stop releases the pause")
            .unwrap();
        assert_eq!(monitor.stopped().await, "first");
    }

    #[test]
    fn a_recorded_run_refuses_pause_and_stop() {
        let monitor = RunMonitor::recorded(RunView::new("old"), FrameStore::default());
        assert_eq!(monitor.set_paused(true), Err(ControlError::Recorded));
        assert_eq!(monitor.request_stop("x"), Err(ControlError::Recorded));
        assert_eq!(monitor.allow_step(), Err(ControlError::Recorded));
    }
}
