//! The runs one monitor server shows: a single run (`optalign run --monitor`, `optalign
//! monitor DIR`) or a bench matrix whose runs come and go, with the matrix's progress.

use std::sync::{Arc, Mutex};

use serde::Serialize;

use super::run::RunMonitor;
use super::view::RunStatus;

/// The runs behind one server (cheap to clone).
#[derive(Clone, Default)]
pub struct Hub {
    inner: Arc<Mutex<HubState>>,
}

#[derive(Default)]
struct HubState {
    runs: Vec<RunMonitor>,
    /// Runs the matrix will make in all, for a bench.
    planned: Option<usize>,
}

/// One run in the matrix overview.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RunEntry {
    pub id: usize,
    pub label: String,
    pub evaluations: usize,
    pub budget: usize,
    pub status: RunStatus,
}

/// The matrix's progress.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct MatrixView {
    pub planned: usize,
    pub finished: usize,
    pub runs: Vec<RunEntry>,
}

impl std::fmt::Debug for Hub {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Hub")
            .field("runs", &self.lock().runs.len())
            .finish_non_exhaustive()
    }
}

impl Hub {
    /// A hub showing one run.
    pub fn single(run: RunMonitor) -> Self {
        let hub = Self::default();
        hub.lock().runs.push(run);
        hub
    }

    /// A hub for a matrix whose runs are added as they start.
    pub fn matrix() -> Self {
        let hub = Self::default();
        hub.lock().planned = Some(0);
        hub
    }

    /// How many runs the matrix will make in all.
    pub fn set_planned(&self, planned: usize) {
        self.lock().planned = Some(planned);
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, HubState> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// Adds a run about to start; its page is `/run/<id>/`.
    pub fn add_run(&self, label: &str) -> RunMonitor {
        let run = RunMonitor::new(label);
        self.lock().runs.push(run.clone());
        run
    }

    pub fn run(&self, id: usize) -> Option<RunMonitor> {
        self.lock().runs.get(id).cloned()
    }

    /// True for a bench's hub (the front page is the matrix).
    pub fn is_matrix(&self) -> bool {
        self.lock().planned.is_some()
    }

    pub fn matrix_view(&self) -> MatrixView {
        let state = self.lock();
        let runs: Vec<RunEntry> = state
            .runs
            .iter()
            .enumerate()
            .map(|(id, run)| {
                let view = run.subscribe();
                let view = view.borrow();
                RunEntry {
                    id,
                    label: view.label.clone(),
                    evaluations: view.evaluations,
                    budget: view.budget,
                    status: view.status.clone(),
                }
            })
            .collect();
        MatrixView {
            planned: state.planned.unwrap_or(runs.len()),
            finished: runs
                .iter()
                .filter(|r| matches!(r.status, RunStatus::Finished { .. }))
                .count(),
            runs,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::RunSummary;
    use crate::task::TaskKind;

    #[test]
    fn the_matrix_counts_its_runs_as_they_start_and_finish() {
        let hub = Hub::matrix();
        hub.set_planned(3);
        assert!(hub.is_matrix());
        let first = hub.add_run("michelson vision seed 0");
        first.begin("michelson", "vision", 0, 40, None);
        hub.add_run("michelson vision seed 1");
        let view = hub.matrix_view();
        assert_eq!((view.planned, view.finished, view.runs.len()), (3, 0, 2));
        assert_eq!(view.runs[0].budget, 40);
        first.finish(&RunSummary {
            task: TaskKind::Michelson,
            policy: "vision".into(),
            seed: 0,
            budget: 40,
            evaluations_used: 8,
            rejected_actions: 0,
            declared_done: true,
            success: true,
            terminal_error: Some(0.3),
            best_error: Some(0.3),
            terminal_commanded_error: None,
            error_trace: Vec::new(),
            best_trace: Vec::new(),
            milestones: None,
            motor_time_s: 0.0,
            camera_time_s: 0.0,
            agent_time_s: 0.0,
            wall_clock_s: 0.0,
            failure: None,
            ended_by: None,
        });
        assert_eq!(hub.matrix_view().finished, 1);
        assert!(hub.run(1).is_some() && hub.run(2).is_none());
    }
}
