//! Building a policy by name. This is the one place that knows every policy; the run loop,
//! the bench and the CLI only see the [`Policy`] trait and, for the baselines the paper gave
//! it to, the privileged objective channel.

use std::io::BufReader;

use super::bo::{BayesOpt, BoSettings};
use super::manual::ManualPolicy;
use super::random::RandomSearch;
use super::vision::VisionPolicy;
use super::vlm::{VlmOptions, VlmPolicy};
use super::{Policy, PrivilegedObjective, TaskBrief};

/// Settings some policies take (everything else lives in the policies' own config).
#[derive(Clone, Debug, Default)]
pub struct PolicyOptions {
    /// Seed for policies that draw random numbers.
    pub seed: u64,
    /// The vision-language model's settings (`vlm` needs them).
    pub vlm: Option<VlmOptions>,
}

/// A policy ready to run, with the objective channel when it is a privileged baseline.
pub struct BuiltPolicy {
    pub policy: Box<dyn Policy>,
    pub objective: Option<PrivilegedObjective>,
}

/// Names accepted by [`build_policy`].
pub fn policy_names() -> &'static [&'static str] {
    &["manual", "random", "bo", "vlm", "vision"]
}

/// Builds the named policy for `brief`.
pub fn build_policy(
    name: &str,
    brief: &TaskBrief,
    options: &PolicyOptions,
) -> anyhow::Result<BuiltPolicy> {
    let objective = PrivilegedObjective::default();
    let (policy, objective): (Box<dyn Policy>, _) = match name {
        "manual" => (
            Box::new(ManualPolicy::new(
                brief.clone(),
                BufReader::new(std::io::stdin()),
            )),
            None,
        ),
        "random" => (
            Box::new(RandomSearch::new(brief, objective.clone(), options.seed)),
            Some(objective),
        ),
        "bo" => (
            Box::new(BayesOpt::new(
                brief,
                objective.clone(),
                options.seed,
                BoSettings::default(),
            )),
            Some(objective),
        ),
        "vlm" => {
            let vlm = options.vlm.as_ref().ok_or_else(|| {
                anyhow::anyhow!(
                    "the vlm policy needs a model: give --model (see `optalign run --help`)"
                )
            })?;
            (Box::new(VlmPolicy::connect(brief, vlm)?), None)
        }
        "vision" => (Box::new(VisionPolicy::new(brief)), None),
        other => anyhow::bail!(
            "unknown policy {other:?}: available: {}",
            policy_names().join(", ")
        ),
    };
    Ok(BuiltPolicy { policy, objective })
}
