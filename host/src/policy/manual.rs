//! The manual policy: a person types each action at a prompt and looks at the frames the
//! run writes. The human baseline, and the best way to get a feel for a task.

use std::io::{BufRead, Write};

use async_trait::async_trait;
use optalign_optics::Station;

use super::{Decision, Feedback, Observation, Policy, PolicyError, TaskBrief};
use crate::task::{Action, RelayAction, TaskKind};

/// Reads actions from a line-based input (standard input in the command line).
pub struct ManualPolicy<R> {
    brief: TaskBrief,
    input: R,
}

impl<R: BufRead + Send> ManualPolicy<R> {
    pub fn new(brief: TaskBrief, input: R) -> Self {
        Self { brief, input }
    }

    fn help(&self) -> &'static str {
        match self.brief.task {
            TaskKind::Michelson => {
                "enter 4 absolute settings: m1a1 m1a2 m2a1 m2a2 [done]   e.g. 1200 -300 0 0"
            }
            TaskKind::Cavity => "enter 2 absolute settings: x y [done]   e.g. -2000 1500",
            TaskKind::Relay => {
                "enter: tilt M1..M4 VERTICAL HORIZONTAL | measure C1..C8 | done   e.g. tilt M1 2000 0"
            }
        }
    }
}

/// Parses one typed line for `task`.
pub fn parse_line(task: TaskKind, line: &str) -> Result<Action, String> {
    let words: Vec<&str> = line.split_whitespace().collect();
    let numbers = |words: &[&str]| -> Result<Vec<i32>, String> {
        words
            .iter()
            .map(|w| {
                w.parse::<i32>()
                    .map_err(|_| format!("{w:?} is not a whole number of steps"))
            })
            .collect()
    };
    match task {
        TaskKind::Michelson | TaskKind::Cavity => {
            let done = words.last() == Some(&"done");
            let values = numbers(&words[..words.len() - usize::from(done)])?;
            match (task, values.as_slice()) {
                (TaskKind::Michelson, &[a, b, c, d]) => Ok(Action::Michelson {
                    command: [a, b, c, d],
                    done,
                }),
                (TaskKind::Cavity, &[x, y]) => Ok(Action::Cavity {
                    command: [x, y],
                    done,
                }),
                _ => Err(format!(
                    "expected {} numbers, got {}",
                    task.axes(),
                    values.len()
                )),
            }
        }
        TaskKind::Relay => match words.as_slice() {
            ["done"] => Ok(Action::Relay(RelayAction::Done)),
            ["measure", station] => {
                let station = station.parse::<Station>().map_err(|e| e.to_string())?;
                Ok(Action::Relay(RelayAction::Measure { station }))
            }
            ["tilt", mirror, vertical, horizontal] => {
                let mirror = match mirror.to_ascii_uppercase().as_str() {
                    "M1" => 0,
                    "M2" => 1,
                    "M3" => 2,
                    "M4" => 3,
                    _ => return Err(format!("mirror must be M1..M4, got {mirror:?}")),
                };
                let values = numbers(&[vertical, horizontal])?;
                Ok(Action::Relay(RelayAction::Tilt {
                    mirror,
                    vertical: values[0],
                    horizontal: values[1],
                }))
            }
            _ => Err("expected tilt M1..M4 V H, measure C1..C8, or done".into()),
        },
    }
}

#[async_trait]
impl<R: BufRead + Send> Policy for ManualPolicy<R> {
    fn name(&self) -> String {
        "manual".into()
    }

    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError> {
        let mut err = std::io::stderr();
        if let Feedback::Rejected { reason, .. } = &observation.feedback {
            let _ = writeln!(err, "{reason}");
        }
        if let Some(path) = &observation.image_path {
            let _ = writeln!(err, "frame: {}", path.display());
        }
        let _ = writeln!(
            err,
            "{} evaluations used, {} left. {}",
            observation.evaluations_used,
            observation.remaining,
            self.help()
        );
        loop {
            let _ = write!(err, "> ");
            let _ = err.flush();
            let mut line = String::new();
            let read = self
                .input
                .read_line(&mut line)
                .map_err(|e| PolicyError::new(format!("reading input: {e}")))?;
            if read == 0 {
                return Err(PolicyError::new("input ended before the task was done"));
            }
            match parse_line(self.brief.task, line.trim()) {
                Ok(action) => return Ok(Decision::new(action)),
                Err(problem) => {
                    let _ = writeln!(err, "{problem}; {}", self.help());
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_each_task_and_explains_mistakes() {
        assert_eq!(
            parse_line(TaskKind::Michelson, "1 -2 3 4 done"),
            Ok(Action::Michelson {
                command: [1, -2, 3, 4],
                done: true
            })
        );
        assert_eq!(
            parse_line(TaskKind::Cavity, "-5 6"),
            Ok(Action::Cavity {
                command: [-5, 6],
                done: false
            })
        );
        assert_eq!(
            parse_line(TaskKind::Relay, "tilt m2 100 -200"),
            Ok(Action::Relay(RelayAction::Tilt {
                mirror: 1,
                vertical: 100,
                horizontal: -200
            }))
        );
        assert_eq!(
            parse_line(TaskKind::Relay, "measure C3"),
            Ok(Action::Relay(RelayAction::Measure {
                station: Station::C3
            }))
        );
        assert!(
            parse_line(TaskKind::Cavity, "1 2 3")
                .unwrap_err()
                .contains("expected 2 numbers")
        );
        assert!(
            parse_line(TaskKind::Relay, "tilt M5 1 1")
                .unwrap_err()
                .contains("M1..M4")
        );
        assert!(
            parse_line(TaskKind::Michelson, "a b c d")
                .unwrap_err()
                .contains("not a whole number")
        );
    }
}
