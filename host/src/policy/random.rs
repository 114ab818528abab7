//! Random search, the paper's second baseline: configurations drawn uniformly over the
//! permitted ranges with the same budgets. Michelson and cavity draws are absolute commands;
//! relay draws are cumulative configurations within the cumulative bounds, reached by
//! `TiltAll` relative moves from the current configuration (several when the draw is
//! farther than one action may move), with the camera fixed at C8. It reads the privileged
//! objective only to remember the best configuration, to which the run's last evaluations
//! return.

use async_trait::async_trait;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::bo::space::{SearchSpace, Trail};
use super::{Decision, Observation, Policy, PolicyError, PrivilegedObjective, TaskBrief};

/// The random-search policy.
pub struct RandomSearch {
    trail: Trail,
    rng: ChaCha8Rng,
    target: Option<Vec<i32>>,
}

impl RandomSearch {
    pub fn new(brief: &TaskBrief, objective: PrivilegedObjective, seed: u64) -> Self {
        Self {
            trail: Trail::new(SearchSpace::of(brief), objective),
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0x5a4d_0e5e),
            target: None,
        }
    }
}

#[async_trait]
impl Policy for RandomSearch {
    fn name(&self) -> String {
        "random".into()
    }

    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError> {
        self.trail.observe(observation)?;
        if let Some(action) = self.trail.closing(observation.remaining) {
            return Ok(Decision::new(action));
        }
        let target = match self.target.take() {
            Some(target) if target != self.trail.current() => target,
            _ => self.trail.space().sample(&mut self.rng),
        };
        let action = self.trail.move_toward(&target);
        self.target = Some(target);
        Ok(Decision::new(action))
    }
}
