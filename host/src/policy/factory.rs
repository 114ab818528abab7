//! Building a policy by name. This is the one place that knows every policy; the run loop,
//! the bench and the CLI only see the [`Policy`] trait and, for the baselines the paper gave
//! it to, the privileged objective channel.

use std::io::BufReader;

use super::manual::ManualPolicy;
use super::{Policy, PrivilegedObjective, TaskBrief};

/// Settings some policies take (everything else lives in the policies' own config).
#[derive(Clone, Debug, Default)]
pub struct PolicyOptions {
    /// Seed for policies that draw random numbers.
    pub seed: u64,
}

/// A policy ready to run, with the objective channel when it is a privileged baseline.
pub struct BuiltPolicy {
    pub policy: Box<dyn Policy>,
    pub objective: Option<PrivilegedObjective>,
}

/// Names accepted by [`build_policy`].
pub fn policy_names() -> &'static [&'static str] {
    &["manual"]
}

/// Builds the named policy for `brief`.
pub fn build_policy(
    name: &str,
    brief: &TaskBrief,
    _options: &PolicyOptions,
) -> anyhow::Result<BuiltPolicy> {
    let policy: Box<dyn Policy> = match name {
        "manual" => Box::new(ManualPolicy::new(
            brief.clone(),
            BufReader::new(std::io::stdin()),
        )),
        other => anyhow::bail!(
            "unknown policy {other:?}: available: {}",
            policy_names().join(", ")
        ),
    };
    Ok(BuiltPolicy {
        policy,
        objective: None,
    })
}
