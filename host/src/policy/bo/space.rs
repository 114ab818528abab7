//! The configuration space the numerical baselines search, and their shared memory of a
//! run. Michelson and cavity configurations are absolute motor settings within the task's
//! ranges, reached in one action. Relay configurations are the cumulative commands of the
//! eight axes within the cumulative bound, reached from the current configuration by
//! `TiltAll` relative moves of at most the per-action bound (so a far target can take
//! several actions, each of which is an evaluation). The camera stays at C8.

use rand::Rng;

use crate::policy::{Feedback, Observation, PolicyError, PrivilegedObjective, TaskBrief};
use crate::task::{Action, RelayAction, TaskKind};

/// The box of configurations and how far one action may move.
#[derive(Clone, Debug, PartialEq)]
pub struct SearchSpace {
    pub task: TaskKind,
    pub lows: Vec<i32>,
    pub highs: Vec<i32>,
    /// Largest change of one axis in one action (relay); `None` for absolute settings.
    pub max_step: Option<i32>,
}

impl SearchSpace {
    /// The permitted ranges of the brief's task.
    pub fn of(brief: &TaskBrief) -> Self {
        let limits = &brief.limits;
        let (ranges, max_step): (Vec<(i32, i32)>, _) = match brief.task {
            TaskKind::Michelson => (
                limits
                    .michelson
                    .ranges
                    .iter()
                    .map(|r| (r.min, r.max))
                    .collect(),
                None,
            ),
            TaskKind::Cavity => (
                limits
                    .cavity
                    .ranges
                    .iter()
                    .map(|r| (r.min, r.max))
                    .collect(),
                None,
            ),
            TaskKind::Relay => {
                let bound = limits.relay.max_cumulative;
                (vec![(-bound, bound); 8], Some(limits.relay.max_step))
            }
        };
        Self {
            task: brief.task,
            lows: ranges.iter().map(|r| r.0).collect(),
            highs: ranges.iter().map(|r| r.1).collect(),
            max_step,
        }
    }

    pub fn dims(&self) -> usize {
        self.lows.len()
    }

    /// The configuration every run starts from: all settings 0.
    pub fn origin(&self) -> Vec<i32> {
        vec![0; self.dims()]
    }

    /// A configuration drawn uniformly from the box (each axis independently).
    pub fn sample(&self, rng: &mut impl Rng) -> Vec<i32> {
        self.lows
            .iter()
            .zip(&self.highs)
            .map(|(&lo, &hi)| rng.random_range(lo..=hi))
            .collect()
    }

    /// Maps a configuration into the unit box.
    pub fn normalise(&self, config: &[i32]) -> Vec<f64> {
        config
            .iter()
            .zip(self.lows.iter().zip(&self.highs))
            .map(|(&c, (&lo, &hi))| f64::from(c - lo) / f64::from(hi - lo).max(1.0))
            .collect()
    }

    /// The nearest configuration to a point of the unit box.
    pub fn denormalise(&self, unit: &[f64]) -> Vec<i32> {
        unit.iter()
            .zip(self.lows.iter().zip(&self.highs))
            .map(|(&u, (&lo, &hi))| {
                let value = f64::from(lo) + u.clamp(0.0, 1.0) * f64::from(hi - lo);
                (value.round() as i32).clamp(lo, hi)
            })
            .collect()
    }

    /// Actions needed to get from `from` to `to`.
    pub fn steps_between(&self, from: &[i32], to: &[i32]) -> usize {
        let largest = from
            .iter()
            .zip(to)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap_or(0);
        match self.max_step {
            _ if largest == 0 => 0,
            None => 1,
            Some(step) => largest.div_ceil(step.unsigned_abs()) as usize,
        }
    }

    /// The configuration one action reaches from `from` on the way to `to`.
    pub fn step_toward(&self, from: &[i32], to: &[i32]) -> Vec<i32> {
        match self.max_step {
            None => to.to_vec(),
            Some(step) => from
                .iter()
                .zip(to)
                .map(|(&a, &b)| a + (b - a).clamp(-step, step))
                .collect(),
        }
    }

    /// The action that moves from `from` to `to` (one reachable step) and, for absolute
    /// tasks, declares done when asked.
    fn action(&self, from: &[i32], to: &[i32], done: bool) -> Action {
        match self.task {
            TaskKind::Michelson => Action::Michelson {
                command: [to[0], to[1], to[2], to[3]],
                done,
            },
            TaskKind::Cavity => Action::Cavity {
                command: [to[0], to[1]],
                done,
            },
            TaskKind::Relay => {
                let mut deltas = [0; 8];
                for (d, (a, b)) in deltas.iter_mut().zip(from.iter().zip(to)) {
                    *d = b - a;
                }
                Action::Relay(RelayAction::TiltAll { deltas })
            }
        }
    }
}

/// A baseline's memory of one run: where it is, every configuration it observed with its
/// privileged objective, and the best of them. It ends each run by returning to the best
/// configuration seen, so the terminal state is the baseline's recommendation.
pub struct Trail {
    space: SearchSpace,
    objective: PrivilegedObjective,
    current: Vec<i32>,
    observations: Vec<(Vec<i32>, f64)>,
    best: Option<usize>,
    returning: bool,
}

impl Trail {
    pub fn new(space: SearchSpace, objective: PrivilegedObjective) -> Self {
        Self {
            current: space.origin(),
            space,
            objective,
            observations: Vec::new(),
            best: None,
            returning: false,
        }
    }

    pub fn space(&self) -> &SearchSpace {
        &self.space
    }

    /// The configuration the last action reached.
    pub fn current(&self) -> &[i32] {
        &self.current
    }

    /// Every configuration observed so far, with its objective.
    pub fn observations(&self) -> &[(Vec<i32>, f64)] {
        &self.observations
    }

    /// The best configuration observed and its objective (the first of equals).
    pub fn best(&self) -> Option<(&[i32], f64)> {
        self.best.map(|i| {
            let (config, value) = &self.observations[i];
            (config.as_slice(), *value)
        })
    }

    /// Records the objective of the current configuration; call once per decision.
    pub fn observe(&mut self, observation: &Observation) -> Result<(), PolicyError> {
        if let Feedback::Rejected { action, reason } = &observation.feedback {
            return Err(PolicyError::new(format!(
                "the baseline's own action {} was rejected: {reason}",
                action.describe()
            )));
        }
        let value = self.objective.read().ok_or_else(|| {
            PolicyError::new("no privileged objective was published for this baseline")
        })?;
        if self.best().is_none_or(|(_, best)| value > best) {
            self.best = Some(self.observations.len());
        }
        self.observations.push((self.current.clone(), value));
        Ok(())
    }

    /// The closing actions: once the remaining evaluations are just enough, head back to
    /// the best configuration seen and declare done there (absolute tasks: one action that
    /// sets it and says done; relay: moves, then done at C8).
    pub fn closing(&mut self, remaining: usize) -> Option<Action> {
        let best = self.best()?.0.to_vec();
        let steps = self.space.steps_between(&self.current, &best);
        let needed = match self.space.max_step {
            None => 1,
            Some(_) => steps + 1,
        };
        if !self.returning && remaining > needed {
            return None;
        }
        self.returning = true;
        Some(match self.space.max_step {
            None => self.go(&best, true),
            Some(_) if steps == 0 => Action::Relay(RelayAction::Done),
            Some(_) => self.go(&best, false),
        })
    }

    /// One action towards `target` (clamped into the box); updates the current position.
    pub fn move_toward(&mut self, target: &[i32]) -> Action {
        self.go(target, false)
    }

    fn go(&mut self, target: &[i32], done: bool) -> Action {
        let clamped: Vec<i32> = target
            .iter()
            .zip(self.space.lows.iter().zip(&self.space.highs))
            .map(|(&t, (&lo, &hi))| t.clamp(lo, hi))
            .collect();
        let next = self.space.step_toward(&self.current, &clamped);
        let action = self.space.action(&self.current, &next, done);
        self.current = next;
        action
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use optalign_optics::Frame;

    use super::*;
    use crate::task::TaskLimits;

    fn brief(task: TaskKind) -> TaskBrief {
        let limits = TaskLimits::default();
        TaskBrief::new(task, &limits, Default::default())
    }

    fn observation(remaining: usize) -> Observation {
        Observation {
            evaluations_used: 0,
            remaining,
            image: Arc::new(Frame::new(1, 1, vec![0]).unwrap()),
            image_path: None,
            feedback: Feedback::Start,
        }
    }

    #[test]
    fn normalising_round_trips_and_bounds_are_the_tasks() {
        let space = SearchSpace::of(&brief(TaskKind::Michelson));
        assert_eq!(space.lows, vec![-8192, -6144, -8192, -6144]);
        let config = vec![-8192, 0, 4000, 6144];
        let unit = space.normalise(&config);
        assert_eq!(unit[0], 0.0);
        assert_eq!(unit[3], 1.0);
        assert_eq!(space.denormalise(&unit), config);
        assert_eq!(
            space.denormalise(&[-0.5, 2.0, 0.5, 0.5]),
            vec![-8192, 6144, 0, 0]
        );
        let relay = SearchSpace::of(&brief(TaskKind::Relay));
        assert_eq!(
            (relay.lows[0], relay.highs[7], relay.max_step),
            (-30_000, 30_000, Some(15_000))
        );
    }

    #[test]
    fn relay_moves_are_split_into_steps_within_the_per_action_bound() {
        let space = SearchSpace::of(&brief(TaskKind::Relay));
        let from = vec![0; 8];
        let to = vec![30_000, -29_000, 100, 0, 0, 0, 0, 15_000];
        assert_eq!(space.steps_between(&from, &to), 2);
        let mid = space.step_toward(&from, &to);
        assert_eq!(mid, vec![15_000, -15_000, 100, 0, 0, 0, 0, 15_000]);
        assert_eq!(space.step_toward(&mid, &to), to);
        let michelson = SearchSpace::of(&brief(TaskKind::Michelson));
        assert_eq!(michelson.steps_between(&[0; 4], &[8192, -6144, 1, 0]), 1);
        assert_eq!(michelson.steps_between(&[5; 4], &[5; 4]), 0);
    }

    #[test]
    fn the_trail_keeps_the_best_and_closes_on_it() {
        let objective = PrivilegedObjective::default();
        let mut trail = Trail::new(SearchSpace::of(&brief(TaskKind::Cavity)), objective.clone());
        objective.publish(-900.0);
        trail.observe(&observation(5)).unwrap();
        assert!(trail.closing(5).is_none());
        trail.move_toward(&[3000, -2000]);
        objective.publish(-100.0);
        trail.observe(&observation(4)).unwrap();
        trail.move_toward(&[9000, 9000]);
        objective.publish(-100.0);
        trail.observe(&observation(3)).unwrap();
        assert_eq!(
            trail.current(),
            &[8000, 5000],
            "targets are clamped into the box"
        );
        assert_eq!(
            trail.best(),
            Some((&[3000, -2000][..], -100.0)),
            "first of equals"
        );
        assert!(trail.closing(2).is_none());
        assert_eq!(
            trail.closing(1),
            Some(Action::Cavity {
                command: [3000, -2000],
                done: true
            })
        );
    }

    #[test]
    fn a_relay_trail_walks_back_then_says_done() {
        let objective = PrivilegedObjective::default();
        let mut trail = Trail::new(SearchSpace::of(&brief(TaskKind::Relay)), objective.clone());
        objective.publish(-1e6);
        trail.observe(&observation(10)).unwrap();
        trail.move_toward(&[20_000; 8]);
        trail.move_toward(&[20_000; 8]);
        assert_eq!(trail.current(), &[20_000; 8]);
        objective.publish(-1e6);
        trail.observe(&observation(8)).unwrap();
        assert!(
            trail.closing(4).is_none(),
            "two steps back and done fit in 3"
        );
        let back = trail.closing(3).unwrap();
        assert_eq!(
            back,
            Action::Relay(RelayAction::TiltAll {
                deltas: [-15_000; 8]
            })
        );
        assert!(matches!(
            trail.closing(2),
            Some(Action::Relay(RelayAction::TiltAll { .. }))
        ));
        assert_eq!(trail.current(), &[0; 8]);
        assert_eq!(trail.closing(1), Some(Action::Relay(RelayAction::Done)));
    }

    #[test]
    fn a_rejected_action_or_a_missing_objective_is_an_error() {
        let mut trail = Trail::new(
            SearchSpace::of(&brief(TaskKind::Cavity)),
            PrivilegedObjective::default(),
        );
        let error = trail.observe(&observation(3)).unwrap_err();
        assert!(error.message.contains("no privileged objective"), "{error}");
        let mut rejected = observation(3);
        rejected.feedback = Feedback::Rejected {
            action: Action::Cavity {
                command: [0, 0],
                done: false,
            },
            reason: "out of range".into(),
        };
        assert!(
            trail
                .observe(&rejected)
                .unwrap_err()
                .message
                .contains("out of range")
        );
    }
}
