//! A full 60-evaluation Michelson run with a trivial policy on the in-process simulated rig
//! (firmware core, mount model, 1920 x 1080 rendering), without writing files.

use criterion::{Criterion, criterion_group, criterion_main};
use optalign::policy::{Decision, Observation, Policy, PolicyError};
use optalign::rig::{MotorPath, SimRig};
use optalign::run::{RunOptions, run_episode};
use optalign::scenario::ScenarioFile;
use optalign::task::{Action, TaskKind};

/// Steps mirror 1 back and forth so every evaluation moves a motor.
struct Sweep(i32);

#[async_trait::async_trait]
impl Policy for Sweep {
    fn name(&self) -> String {
        "sweep".into()
    }

    async fn decide(&mut self, _: &Observation) -> Result<Decision, PolicyError> {
        self.0 = if self.0 > 0 { -400 } else { 400 };
        Ok(Decision::new(Action::Michelson {
            command: [self.0, -self.0, 0, 0],
            done: false,
        }))
    }
}

fn bench_episode(c: &mut Criterion) {
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    let scenario = ScenarioFile::default();
    let options = RunOptions {
        out_dir: None,
        ..RunOptions::default()
    };
    let mut group = c.benchmark_group("episode");
    group.sample_size(10);
    group.bench_function(
        "michelson 60 evaluations, trivial policy, in-process rig",
        |b| {
            b.to_async(&runtime).iter(|| async {
                let mut rig = SimRig::new(TaskKind::Michelson, &scenario, 0, MotorPath::InProcess)
                    .await
                    .unwrap();
                let summary = run_episode(&mut rig, &mut Sweep(0), None, &scenario.tasks, &options)
                    .await
                    .unwrap();
                assert_eq!(summary.evaluations_used, 60);
            })
        },
    );
    group.finish();
}

criterion_group!(benches, bench_episode);
criterion_main!(benches);
