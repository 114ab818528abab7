//! `VectorEpisodes`: a batch of simulated episodes of one task stepped together in Rust,
//! the GIL released and the episodes spread over threads (one contiguous share each), for
//! the native vector environment. Each episode is a [`Stepper`], exactly what the single
//! environment steps, so a batch gives each seed's episode unchanged.

use std::path::PathBuf;
use std::sync::{Arc, Mutex, MutexGuard};

use optalign::task::{Action, TaskKind};
use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use pyo3::types::PyByteArray;

use crate::errors::invalid;
use crate::stepper::{Acted, Setup, State, StepError, Stepper};

/// Most episodes one batch may hold.
const MAX_EPISODES: usize = 4096;

/// A batch of episodes of one task (Michelson or cavity).
#[pyclass(module = "optalign._native")]
pub struct VectorEpisodes {
    setup: Arc<Setup>,
    threads: usize,
    steppers: Mutex<Vec<Stepper>>,
}

/// What to do with one episode in a step.
enum Order {
    Act(Action),
    Reset(u64),
}

#[pymethods]
impl VectorEpisodes {
    #[new]
    #[pyo3(signature = (task, count, scenario=None, motors="in-process", obs_size=None, threads=None))]
    fn new(
        task: &str,
        count: usize,
        scenario: Option<PathBuf>,
        motors: &str,
        obs_size: Option<(u32, u32)>,
        threads: Option<usize>,
    ) -> PyResult<Self> {
        let setup = Arc::new(Setup::new(task, scenario, motors, obs_size).map_err(invalid)?);
        if setup.task == TaskKind::Relay {
            return Err(invalid(
                "the native vector environment steps the Michelson and the cavity; run relay environments in gymnasium.vector.AsyncVectorEnv",
            ));
        }
        if setup.frame_len() == 0 {
            return Err(invalid(format!("the {} camera has no size", setup.task)));
        }
        if !(1..=MAX_EPISODES).contains(&count) {
            return Err(invalid(format!(
                "num_envs must be 1 to {MAX_EPISODES}, got {count}"
            )));
        }
        let cores = std::thread::available_parallelism().map_or(1, usize::from);
        let threads = threads.unwrap_or(cores);
        if threads == 0 {
            return Err(invalid("threads must be at least 1"));
        }
        let steppers = (0..count)
            .map(|_| Stepper::new(setup.clone()))
            .collect::<PyResult<Vec<_>>>()?;
        Ok(Self {
            threads: threads.min(count),
            setup,
            steppers: Mutex::new(steppers),
        })
    }

    /// Starts episode `i` with `seeds[i]`; returns every first image, one after another,
    /// and each episode's state.
    fn reset<'py>(
        &self,
        py: Python<'py>,
        seeds: Vec<u64>,
    ) -> PyResult<(Bound<'py, PyByteArray>, Vec<State>)> {
        self.check_count(seeds.len(), "seeds")?;
        let orders = seeds.into_iter().map(Order::Reset).collect();
        self.run(py, orders)
    }

    /// One step of every episode: the absolute commands, row by row (`commands` holds
    /// count x axes values), `done[i]` declaring episode `i` done after its command. An
    /// episode with a seed in `resets` is reset with it instead (its command is ignored):
    /// the next-step autoreset of Gymnasium's vector environments. Returns every image
    /// and each episode's state. A command outside the task's bounds raises before any
    /// episode moves.
    fn step<'py>(
        &self,
        py: Python<'py>,
        commands: Vec<i64>,
        done: Vec<bool>,
        resets: Vec<Option<u64>>,
    ) -> PyResult<(Bound<'py, PyByteArray>, Vec<State>)> {
        let count = self.count()?;
        let axes = self.setup.task.axes();
        if commands.len() != count * axes {
            return Err(invalid(format!(
                "{count} environments of the {} task take {count} x {axes} values, got {}",
                self.setup.task,
                commands.len()
            )));
        }
        self.check_count(done.len(), "done flags")?;
        self.check_count(resets.len(), "reset seeds")?;
        let mut orders = Vec::with_capacity(count);
        for (index, ((command, done), reset)) in commands
            .chunks_exact(axes)
            .zip(done)
            .zip(resets)
            .enumerate()
        {
            orders.push(match reset {
                Some(seed) => Order::Reset(seed),
                None => {
                    let action = self
                        .setup
                        .command(command, done)
                        .and_then(|action| self.setup.check_bounds(&action).map(|()| action))
                        .map_err(|reason| invalid(format!("environment {index}: {reason}")))?;
                    Order::Act(action)
                }
            });
        }
        self.run(py, orders)
    }

    /// The observation's (height, width).
    fn frame_shape(&self) -> (u32, u32) {
        self.setup.frame_shape()
    }

    /// The scenario's task bounds and budgets, as JSON (`[tasks]` of the scenario file).
    fn limits_json(&self) -> PyResult<String> {
        self.setup.limits_json().map_err(invalid)
    }

    fn budget(&self) -> usize {
        self.setup.budget()
    }

    /// Threads a step is spread over.
    fn threads(&self) -> usize {
        self.threads
    }

    /// Episode `index`'s hidden state as JSON: the score and the true shaft positions.
    fn truth_json(&self, index: usize) -> PyResult<String> {
        let steppers = self.lock()?;
        let stepper = steppers
            .get(index)
            .ok_or_else(|| invalid(format!("no environment {index}")))?;
        Ok(stepper.truth_json()?)
    }
}

impl VectorEpisodes {
    fn lock(&self) -> PyResult<MutexGuard<'_, Vec<Stepper>>> {
        self.steppers.lock().map_err(|_| {
            PyRuntimeError::new_err("an earlier step panicked; make the environment anew")
        })
    }

    fn count(&self) -> PyResult<usize> {
        Ok(self.lock()?.len())
    }

    fn check_count(&self, given: usize, what: &str) -> PyResult<()> {
        let count = self.count()?;
        if given == count {
            Ok(())
        } else {
            Err(invalid(format!(
                "{count} environments take {count} {what}, got {given}"
            )))
        }
    }

    /// Carries out one order per episode, the episodes shared out over the threads with
    /// the GIL released.
    fn run<'py>(
        &self,
        py: Python<'py>,
        orders: Vec<Order>,
    ) -> PyResult<(Bound<'py, PyByteArray>, Vec<State>)> {
        let mut guard = self.lock()?;
        let steppers: &mut [Stepper] = &mut guard;
        let frame_len = self.setup.frame_len();
        let mut images = vec![0u8; frame_len * steppers.len()];
        let share = steppers.len().div_ceil(self.threads);
        let states = py.detach(|| {
            std::thread::scope(|scope| {
                let workers: Vec<_> = steppers
                    .chunks_mut(share)
                    .zip(images.chunks_mut(share * frame_len))
                    .zip(orders.chunks(share))
                    .map(|((steppers, images), orders)| {
                        scope.spawn(move || carry_out(steppers, images, orders))
                    })
                    .collect();
                workers
                    .into_iter()
                    .map(|worker| {
                        worker.join().unwrap_or_else(|_| {
                            Err(StepError::State(
                                "a simulated rig panicked; make the environment anew".into(),
                            ))
                        })
                    })
                    .collect::<Vec<_>>()
            })
        });
        let mut all = Vec::with_capacity(orders.len());
        for share in states {
            all.extend(share?);
        }
        Ok((PyByteArray::new(py, &images), all))
    }
}

/// Carries out `orders` on `steppers` (one each), writing each image into its slot of
/// `images`.
fn carry_out(
    steppers: &mut [Stepper],
    images: &mut [u8],
    orders: &[Order],
) -> Result<Vec<State>, StepError> {
    let frame_len = images.len() / steppers.len().max(1);
    steppers
        .iter_mut()
        .zip(images.chunks_mut(frame_len))
        .zip(orders)
        .map(|((stepper, slot), order)| {
            let image = match order {
                Order::Reset(seed) => stepper.reset(*seed).map_err(StepError::Failed)?,
                Order::Act(action) => match stepper.act(action, true)? {
                    Acted::Image(image) => image,
                    Acted::Rejected(reason) => return Err(StepError::Invalid(reason)),
                },
            };
            if image.len() != slot.len() {
                return Err(StepError::Failed(anyhow::anyhow!(
                    "the rig rendered {} pixels for a frame of {}",
                    image.len(),
                    slot.len()
                )));
            }
            slot.copy_from_slice(&image);
            stepper.state()
        })
        .collect()
}
