//! The numerical baselines end to end on simulated rigs: random search draws within the
//! permitted ranges and covers them, neither baseline ever sends an action the task
//! rejects, both end on the best configuration they saw, and on the relay they keep the
//! camera at C8.

use optalign::policy::{PolicyOptions, TaskBrief, build_policy};
use optalign::rig::{MotorPath, SimRig};
use optalign::run::{RunOptions, RunSummary, StepRecord, run_episode};
use optalign::scenario::ScenarioFile;
use optalign::task::{Action, RelayAction, TaskKind};

/// Runs `policy` on `task` and returns the summary and every executed step.
async fn run(
    task: TaskKind,
    policy: &str,
    seed: u64,
    scenario: &ScenarioFile,
) -> (RunSummary, Vec<StepRecord>) {
    let dir = tempfile::tempdir().unwrap();
    let brief = TaskBrief::new(task, &scenario.tasks, scenario.geometry(task));
    let mut built = build_policy(
        policy,
        &brief,
        &PolicyOptions {
            seed,
            ..PolicyOptions::default()
        },
    )
    .unwrap();
    assert!(
        built.objective.is_some(),
        "{policy} is a privileged baseline"
    );
    let mut rig = SimRig::new(task, scenario, seed, MotorPath::InProcess)
        .await
        .unwrap();
    let options = RunOptions {
        out_dir: Some(dir.path().to_owned()),
        save_frames: false,
        seed,
        ..RunOptions::default()
    };
    let summary = run_episode(
        &mut rig,
        built.policy.as_mut(),
        built.objective.as_ref(),
        &scenario.tasks,
        &options,
    )
    .await
    .unwrap();
    let text = std::fs::read_to_string(dir.path().join("transcript.jsonl")).unwrap();
    let steps = text
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap())
        .filter(|value| value["type"] == "step")
        .map(|value| serde_json::from_value(value).unwrap())
        .collect();
    (summary, steps)
}

#[tokio::test]
async fn random_search_stays_in_bounds_and_covers_the_ranges() {
    let mut scenario = ScenarioFile::default();
    scenario.tasks.michelson.budget = 30;
    scenario.tasks.cavity.budget = 20;
    let limits = &scenario.tasks;
    let (summary, steps) = run(TaskKind::Michelson, "random", 3, &scenario).await;
    assert_eq!(summary.rejected_actions, 0);
    assert!(summary.failure.is_none(), "{:?}", summary.failure);
    assert_eq!(summary.evaluations_used, limits.michelson.budget);
    let commands: Vec<[i32; 4]> = steps
        .iter()
        .map(|s| match s.action {
            Action::Michelson { command, .. } => command,
            ref other => panic!("not a Michelson action: {other:?}"),
        })
        .collect();
    for (axis, range) in limits.michelson.ranges.iter().enumerate() {
        let values: Vec<i32> = commands.iter().map(|c| c[axis]).collect();
        assert!(values.iter().all(|v| range.contains(*v)), "axis {axis}");
        let (low, high) = (values.iter().min().unwrap(), values.iter().max().unwrap());
        let span = f64::from(high - low) / f64::from(range.max - range.min);
        assert!(
            span > 0.8,
            "axis {axis}: 60 uniform draws span only {span:.2}"
        );
    }
    // The last action returns to the best configuration seen, and says done.
    let last = steps.last().unwrap();
    assert!(last.action.is_done());
    assert_eq!(summary.terminal_error, summary.best_error);

    let (summary, steps) = run(TaskKind::Cavity, "random", 1, &scenario).await;
    assert_eq!(summary.rejected_actions, 0);
    for step in &steps {
        let Action::Cavity { command, .. } = step.action else {
            panic!("not a cavity action")
        };
        assert!(limits.cavity.check(&command).is_ok(), "{command:?}");
    }
}

#[tokio::test]
async fn relay_baselines_keep_the_camera_at_c8_within_the_cumulative_bounds() {
    let mut scenario = ScenarioFile::default();
    scenario.tasks.relay.budget = 12;
    for policy in ["random", "bo"] {
        let (summary, steps) = run(TaskKind::Relay, policy, 2, &scenario).await;
        assert_eq!(summary.rejected_actions, 0, "{policy}");
        assert!(summary.failure.is_none(), "{policy}: {:?}", summary.failure);
        let mut cumulative = [0i64; 8];
        let mut largest = 0i64;
        for step in &steps {
            match &step.action {
                Action::Relay(RelayAction::TiltAll { deltas }) => {
                    for (total, delta) in cumulative.iter_mut().zip(deltas) {
                        assert!(delta.abs() <= scenario.tasks.relay.max_step);
                        *total += i64::from(*delta);
                        largest = largest.max(total.abs());
                    }
                }
                Action::Relay(RelayAction::Done) => {}
                other => panic!("{policy} sent {other:?}; baselines only tilt all and end"),
            }
        }
        assert!(largest <= i64::from(scenario.tasks.relay.max_cumulative));
        assert!(
            largest > 15_000,
            "{policy}: the search never left the neighbourhood of the start ({largest})"
        );
        assert!(
            !summary.success,
            "{policy} cannot align the relay from C8 alone"
        );
    }
}

#[tokio::test]
async fn bayesian_optimisation_beats_random_search_on_the_cavity() {
    let mut scenario = ScenarioFile::default();
    scenario.tasks.cavity.budget = 20;
    let (bo, steps) = run(TaskKind::Cavity, "bo", 0, &scenario).await;
    let (random, _) = run(TaskKind::Cavity, "random", 0, &scenario).await;
    assert_eq!(bo.rejected_actions, 0);
    assert!(steps.last().unwrap().action.is_done());
    assert_eq!(bo.terminal_error, bo.best_error);
    assert!(
        bo.terminal_error.unwrap() < random.terminal_error.unwrap(),
        "bo {:?} vs random {:?}",
        bo.terminal_error,
        random.terminal_error
    );
    // Every GP proposal records what the model expected of it.
    assert!(steps.iter().any(|s| {
        s.claims
            .as_ref()
            .is_some_and(|c| c["expected_improvement"].is_number())
    }));
}
