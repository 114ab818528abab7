//! Bayesian optimisation, the paper's privileged baseline: a Gaussian process with a
//! Matérn-5/2 kernel (per-axis length scales, hyperparameters fitted by marginal
//! likelihood) on the task's permitted box, and expected improvement with xi = 0.01.
//!
//! The objective is read only through [`PrivilegedObjective`]: minus the error for the
//! Michelson and the cavity, and for the relay minus the pixel distance from the C8 centre
//! with -1e6 whenever no beam reaches C8 (the camera never leaves C8). Inputs are
//! normalised to the unit box, outputs standardised. A few uniform random configurations
//! start the search; the last evaluations return to the best configuration seen.

pub mod acquisition;
pub mod gp;
pub mod kernel;
pub mod optimise;
pub mod space;

use std::time::Instant;

use async_trait::async_trait;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde_json::json;

use self::acquisition::{AcquisitionSearch, maximise_expected_improvement};
use self::gp::{GaussianProcess, Hyperparameters};
use self::space::{SearchSpace, Trail};
use super::{Decision, Observation, Policy, PolicyError, PrivilegedObjective, TaskBrief};

/// Settings of the optimiser.
#[derive(Clone, Debug, PartialEq)]
pub struct BoSettings {
    /// Uniform random configurations after the start, before the GP proposes.
    pub initial_points: usize,
    /// Random restarts of the likelihood fit, besides the default guess and the last fit.
    pub random_restarts: usize,
    pub acquisition: AcquisitionSearch,
}

impl Default for BoSettings {
    fn default() -> Self {
        Self {
            initial_points: 5,
            random_restarts: 1,
            acquisition: AcquisitionSearch::default(),
        }
    }
}

/// The Bayesian-optimisation policy.
pub struct BayesOpt {
    trail: Trail,
    rng: ChaCha8Rng,
    settings: BoSettings,
    hyper: Option<Hyperparameters>,
}

impl BayesOpt {
    pub fn new(
        brief: &TaskBrief,
        objective: PrivilegedObjective,
        seed: u64,
        settings: BoSettings,
    ) -> Self {
        Self {
            trail: Trail::new(SearchSpace::of(brief), objective),
            rng: ChaCha8Rng::seed_from_u64(seed ^ 0xb0_5eed),
            settings,
            hyper: None,
        }
    }

    /// The next target configuration and what the GP expects of it.
    fn propose(&mut self) -> Result<(Vec<i32>, Option<serde_json::Value>), PolicyError> {
        let space = self.trail.space();
        let observations = self.trail.observations();
        if observations.len() <= self.settings.initial_points {
            return Ok((space.sample(&mut self.rng), None));
        }
        let inputs: Vec<Vec<f64>> = observations
            .iter()
            .map(|(config, _)| space.normalise(config))
            .collect();
        let outputs: Vec<f64> = observations.iter().map(|(_, y)| *y).collect();
        let (best_config, best_value) = self
            .trail
            .best()
            .ok_or_else(|| PolicyError::new("no observation yet"))?;
        let incumbent = space.normalise(best_config);
        let informative = outputs.iter().any(|y| *y != outputs[0]);
        let fitted = if informative {
            GaussianProcess::fit(
                inputs,
                &outputs,
                self.hyper.as_ref(),
                self.settings.random_restarts,
                &mut self.rng,
            )
        } else {
            // A flat objective carries no information to fit: the default GP makes
            // expected improvement pick the configuration farthest from those tried.
            GaussianProcess::condition(
                inputs,
                &outputs,
                &Hyperparameters::default_for(space.dims()),
            )
        };
        let gp = fitted.map_err(|e| PolicyError::new(format!("Gaussian process: {e}")))?;
        if informative {
            self.hyper = Some(gp.hyperparameters());
        }
        let (unit, ei) = maximise_expected_improvement(
            &gp,
            gp.standardise(best_value),
            &incumbent,
            &self.settings.acquisition,
            &mut self.rng,
        );
        let prediction = gp.predict(&unit);
        let target = space.denormalise(&unit);
        let claims = json!({
            "target": target,
            "predicted_objective": prediction.mean,
            "predicted_std": prediction.variance.sqrt(),
            "expected_improvement": ei,
            "length_scales": gp.hyperparameters().length_scales,
        });
        Ok((target, Some(claims)))
    }
}

#[async_trait]
impl Policy for BayesOpt {
    fn name(&self) -> String {
        "bo".into()
    }

    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError> {
        let started = Instant::now();
        self.trail.observe(observation)?;
        let (action, claims) = match self.trail.closing(observation.remaining) {
            Some(action) => (action, None),
            None => {
                let (target, claims) = self.propose()?;
                (self.trail.move_toward(&target), claims)
            }
        };
        Ok(Decision {
            action,
            claims,
            latency_s: started.elapsed().as_secs_f64(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs BO's propose/observe cycle on a function of the unit square (as a 2-axis
    /// cavity-shaped space) for `budget` evaluations; returns the best value found.
    fn optimise(f: impl Fn(&[f64]) -> f64, budget: usize, seed: u64) -> (Vec<f64>, f64) {
        let limits = crate::task::TaskLimits::default();
        let brief = TaskBrief {
            task: crate::task::TaskKind::Cavity,
            budget,
            limits,
            geometry: Default::default(),
        };
        let objective = PrivilegedObjective::default();
        let mut bo = BayesOpt::new(&brief, objective.clone(), seed, BoSettings::default());
        let space = SearchSpace::of(&brief);
        for _ in 0..budget {
            objective.publish(f(&space.normalise(bo.trail.current())));
            let observation = Observation {
                evaluations_used: 0,
                remaining: budget + 10,
                image: std::sync::Arc::new(optalign_optics::Frame::new(1, 1, vec![0]).unwrap()),
                image_path: None,
                feedback: crate::policy::Feedback::Start,
            };
            bo.trail.observe(&observation).unwrap();
            let (target, _) = bo.propose().unwrap();
            bo.trail.move_toward(&target);
        }
        let (config, value) = bo.trail.best().unwrap();
        (space.normalise(config), value)
    }

    #[test]
    fn finds_the_optimum_of_a_smooth_function_and_beats_random_search() {
        // A tilted Gaussian bump with its peak (value 0) at (0.73, 0.21) on a slope.
        let peak = [0.73, 0.21];
        let f = |x: &[f64]| {
            let d2 = ((x[0] - peak[0]) / 0.25).powi(2) + ((x[1] - peak[1]) / 0.15).powi(2);
            2.0 * ((-0.5 * d2).exp() - 1.0) - 0.3 * x[0]
        };
        let optimum = f(&peak);
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let random_best = (0..25)
            .map(|_| {
                let x = [
                    rand::Rng::random::<f64>(&mut rng),
                    rand::Rng::random(&mut rng),
                ];
                f(&x)
            })
            .fold(f64::MIN, f64::max);
        for seed in 0..2 {
            let (x, value) = optimise(f, 25, seed);
            assert!(
                optimum - value < 0.01,
                "seed {seed}: best {value} at {x:?}, optimum {optimum}"
            );
            assert!(
                value > random_best,
                "seed {seed}: {value} <= random {random_best}"
            );
        }
    }
}
