//! The three alignment tasks: what an agent may do (actions and their bounds), how many
//! evaluations it gets, and how the hidden truth is scored. Validation happens here, before
//! a rig executes anything: a rejected action comes back with a reason and does not spend
//! an evaluation.

pub mod cavity;
mod geometry;
pub mod michelson;
pub mod relay;

use serde::{Deserialize, Serialize};

pub use cavity::CavityLimits;
pub use geometry::BenchGeometry;
pub use michelson::MichelsonLimits;
pub use relay::{RelayAction, RelayLimits};

/// Which alignment task.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum TaskKind {
    /// Michelson interferometer: overlap two beams at the camera centre (4 absolute axes).
    Michelson,
    /// Two-mirror cavity: put the dim secondary beam on the bright primary (2 absolute axes).
    Cavity,
    /// Four-mirror relay: get the beam through four mirrors to a centred spot at C8
    /// (8 relative axes, a movable camera).
    Relay,
}

impl TaskKind {
    pub const ALL: [TaskKind; 3] = [TaskKind::Michelson, TaskKind::Cavity, TaskKind::Relay];

    pub fn name(self) -> &'static str {
        match self {
            Self::Michelson => "michelson",
            Self::Cavity => "cavity",
            Self::Relay => "relay",
        }
    }

    /// Number of motor axes the task drives.
    pub fn axes(self) -> usize {
        match self {
            Self::Michelson => 4,
            Self::Cavity => 2,
            Self::Relay => 8,
        }
    }
}

impl std::fmt::Display for TaskKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// One agent action. Michelson and cavity commands are absolute motor settings (visible
/// settings start at 0); `done` applies the command and ends the run. Relay actions are
/// relative tilts, camera moves, or done.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "task", rename_all = "snake_case")]
pub enum Action {
    Michelson { command: [i32; 4], done: bool },
    Cavity { command: [i32; 2], done: bool },
    Relay(RelayAction),
}

impl Action {
    pub fn task(&self) -> TaskKind {
        match self {
            Self::Michelson { .. } => TaskKind::Michelson,
            Self::Cavity { .. } => TaskKind::Cavity,
            Self::Relay(_) => TaskKind::Relay,
        }
    }

    /// Whether the agent declares the task complete with this action.
    pub fn is_done(&self) -> bool {
        match self {
            Self::Michelson { done, .. } | Self::Cavity { done, .. } => *done,
            Self::Relay(action) => matches!(action, RelayAction::Done),
        }
    }

    /// A short human-readable form, for logs and filmstrips.
    pub fn describe(&self) -> String {
        match self {
            Self::Michelson { command, done } => {
                format!(
                    "m1=({}, {}) m2=({}, {}){}",
                    command[0],
                    command[1],
                    command[2],
                    command[3],
                    done_suffix(*done)
                )
            }
            Self::Cavity { command, done } => {
                format!("x={} y={}{}", command[0], command[1], done_suffix(*done))
            }
            Self::Relay(action) => action.describe(),
        }
    }
}

fn done_suffix(done: bool) -> &'static str {
    if done { " (done)" } else { "" }
}

/// The permitted ranges and budgets of all three tasks (scenario table `[tasks]`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TaskLimits {
    pub michelson: MichelsonLimits,
    pub cavity: CavityLimits,
    pub relay: RelayLimits,
}

impl TaskLimits {
    pub fn budget(&self, task: TaskKind) -> usize {
        match task {
            TaskKind::Michelson => self.michelson.budget,
            TaskKind::Cavity => self.cavity.budget,
            TaskKind::Relay => self.relay.budget,
        }
    }

    /// Checks ranges; the error names the field.
    pub fn validate(&self) -> Result<(), String> {
        self.michelson.validate()?;
        self.cavity.validate()?;
        self.relay.validate()
    }
}

/// An inclusive range of absolute motor settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Range {
    pub min: i32,
    pub max: i32,
}

impl Range {
    pub const fn symmetric(half_width: i32) -> Self {
        Self {
            min: -half_width,
            max: half_width,
        }
    }

    pub fn contains(self, value: i32) -> bool {
        (self.min..=self.max).contains(&value)
    }
}

impl std::fmt::Display for Range {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "[{}, {}]", self.min, self.max)
    }
}

/// Checks absolute commands against per-axis ranges; the reason names every bad axis.
pub fn check_absolute(names: &[&str], ranges: &[Range], command: &[i32]) -> Result<(), String> {
    let problems: Vec<String> = names
        .iter()
        .zip(ranges)
        .zip(command)
        .filter(|((_, range), value)| !range.contains(**value))
        .map(|((name, range), value)| format!("{name}={value} is outside {range}"))
        .collect();
    if problems.is_empty() {
        Ok(())
    } else {
        Err(format!("rejected, nothing moved: {}", problems.join("; ")))
    }
}

pub(crate) fn check_budget(field: &str, budget: usize) -> Result<(), String> {
    if (1..=10_000).contains(&budget) {
        Ok(())
    } else {
        Err(format!(
            "{field}: budget must be 1..=10000 evaluations, got {budget}"
        ))
    }
}
