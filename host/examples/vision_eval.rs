//! Evaluates the image-only "vision" policy on the ten default seeds of every task in
//! simulation and prints a table per task: success, terminal error, evaluations used.
//! Run with `cargo run --release -p optalign --example vision_eval [-- <task>]`.

use std::sync::Arc;

use optalign::bench::{MatrixOptions, RunSpec, run_one};
use optalign::scenario::ScenarioFile;
use optalign::task::TaskKind;

#[tokio::main(flavor = "current_thread")]
async fn main() -> anyhow::Result<()> {
    let only = std::env::args().nth(1);
    let scenario = Arc::new(ScenarioFile::default());
    for task in TaskKind::ALL {
        if only.as_deref().is_some_and(|name| name != task.name()) {
            continue;
        }
        println!("{task}\nseed  success  done  error  evaluations  milestones");
        let (mut errors, mut evaluations, mut successes) = (Vec::new(), Vec::new(), 0);
        for seed in 0..10 {
            let spec = RunSpec {
                task,
                policy: "vision".into(),
                seed,
                scenario: scenario.clone(),
                setting: None,
                out_dir: None,
            };
            let summary = run_one(&spec, &MatrixOptions::default()).await?.summary;
            let error = summary.terminal_error.unwrap_or(f64::NAN);
            println!(
                "{seed:>4}  {:>7}  {:>4}  {error:>7.1}  {:>11}  {:?}",
                summary.success,
                summary.declared_done,
                summary.evaluations_used,
                summary.milestones
            );
            successes += usize::from(summary.success);
            errors.push(error);
            evaluations.push(summary.evaluations_used);
        }
        evaluations.sort_unstable();
        let mean = errors.iter().sum::<f64>() / errors.len() as f64;
        let median = f64::from((evaluations[4] + evaluations[5]) as u32) / 2.0;
        println!(
            "{task}: success {successes}/10, mean error {mean:.1}, median evaluations {median}\n"
        );
    }
    Ok(())
}
