//! What an earlier bench left in its output folder, for `optalign bench --resume`: a run
//! whose folder holds its `summary.json` and the very scenario this bench would give it is
//! read back instead of run again, so a sweep stopped by a crash, a power cut or Ctrl-C
//! picks up where it stopped. Anything less (no summary: the run was cut short; another
//! scenario; a summary of another run; a file that does not parse) runs again.

use std::path::Path;

use super::RunSpec;
use crate::run::SCENARIO_FILE;
use crate::run::{RunSummary, SUMMARY_FILE};

/// The summary of `spec`'s run finished in `dir` by an earlier bench, when there is one.
pub fn finished(spec: &RunSpec, dir: &Path) -> Option<RunSummary> {
    let summary_path = dir.join(SUMMARY_FILE);
    let summary_bytes = std::fs::read(&summary_path).ok()?;
    let recorded = std::fs::read_to_string(dir.join(SCENARIO_FILE)).ok()?;
    let wanted = toml::to_string(spec.scenario.as_ref()).ok()?;
    if recorded != wanted {
        tracing::info!("{}: another scenario; run again", dir.display());
        return None;
    }
    match serde_json::from_slice::<RunSummary>(&summary_bytes) {
        Ok(summary)
            if summary.task == spec.task
                && summary.policy == spec.policy
                && summary.seed == spec.seed =>
        {
            Some(summary)
        }
        Ok(_) => {
            tracing::warn!(
                "{}: the summary of another run; run again",
                summary_path.display()
            );
            None
        }
        Err(error) => {
            tracing::warn!(
                "{}: unreadable ({error}); run again",
                summary_path.display()
            );
            None
        }
    }
}
