//! The simulated rig end to end: exact alignment scores zero in all three tasks, the
//! in-process and over-the-peer motor paths agree, a run writes its transcript, and frames
//! come at a smaller size when asked.

use optalign::policy::{Decision, Observation, Policy, PolicyError};
use optalign::rig::{MotorPath, Rig, Score, SimRig};
use optalign::run::{RunOptions, run_episode};
use optalign::scenario::ScenarioFile;
use optalign::task::{Action, RelayAction, TaskKind};
use optalign_optics::Station;
use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};

fn aligning_actions(task: TaskKind, scenario: &ScenarioFile, seed: u64) -> Vec<Action> {
    match task {
        TaskKind::Michelson => {
            let command = michelson_offsets(&scenario.michelson, seed).map(|o| -o);
            vec![Action::Michelson {
                command,
                done: true,
            }]
        }
        TaskKind::Cavity => {
            let command = cavity_offsets(&scenario.cavity, seed).map(|o| -o);
            vec![Action::Cavity {
                command,
                done: true,
            }]
        }
        TaskKind::Relay => {
            let deltas = relay_offsets(&scenario.relay, seed).unwrap().map(|o| -o);
            vec![
                Action::Relay(RelayAction::Measure {
                    station: Station::C1,
                }),
                Action::Relay(RelayAction::TiltAll { deltas }),
                Action::Relay(RelayAction::Measure {
                    station: Station::C8,
                }),
                Action::Relay(RelayAction::Done),
            ]
        }
    }
}

#[tokio::test]
async fn the_exact_negative_offsets_align_every_task() {
    let scenario = ScenarioFile::default();
    for task in TaskKind::ALL {
        for seed in [0, 3] {
            let mut rig = SimRig::new(task, &scenario, seed, MotorPath::InProcess)
                .await
                .unwrap();
            let before = rig.score();
            for action in aligning_actions(task, &scenario, seed) {
                rig.execute(&action).await.unwrap();
            }
            match rig.score() {
                Score::Michelson(score) => {
                    assert!(score.error_px < 1e-6, "{score:?}");
                    assert!(score.commanded_error_px < 1e-6);
                }
                Score::Cavity(score) => assert!(score.error_steps < 1e-9 && score.success),
                Score::Relay(score) => {
                    assert!(
                        score.through_all_mirrors && score.aligned == [true; 4],
                        "{score:?}"
                    );
                    let [x, y] = score.c8_offset_px.unwrap();
                    assert!(x.hypot(y) < 1e-3);
                }
            }
            assert_ne!(
                before,
                rig.score(),
                "{task} seed {seed} did not start aligned"
            );
        }
    }
}

#[tokio::test]
async fn in_process_and_peer_rigs_agree() {
    let scenario = ScenarioFile::default();
    for task in TaskKind::ALL {
        let mut local = SimRig::new(task, &scenario, 1, MotorPath::InProcess)
            .await
            .unwrap();
        let mut remote = SimRig::new(task, &scenario, 1, MotorPath::Peer)
            .await
            .unwrap();
        assert_eq!(
            local.initial_image().await.unwrap(),
            remote.initial_image().await.unwrap()
        );
        let probes: Vec<Action> = match task {
            TaskKind::Michelson => vec![
                Action::Michelson {
                    command: [1500, -800, 0, 0],
                    done: false,
                },
                Action::Michelson {
                    command: [-300, 400, 2000, -100],
                    done: false,
                },
            ],
            TaskKind::Cavity => vec![
                Action::Cavity {
                    command: [3000, -2000],
                    done: false,
                },
                Action::Cavity {
                    command: [-150, 35],
                    done: false,
                },
            ],
            TaskKind::Relay => vec![
                Action::Relay(RelayAction::Measure {
                    station: Station::C1,
                }),
                Action::Relay(RelayAction::Tilt {
                    mirror: 0,
                    vertical: 2000,
                    horizontal: -1500,
                }),
                Action::Relay(RelayAction::Tilt {
                    mirror: 0,
                    vertical: -25,
                    horizontal: 10,
                }),
            ],
        };
        for action in probes.iter().chain(&aligning_actions(task, &scenario, 1)) {
            let a = local.execute(action).await.unwrap();
            let b = remote.execute(action).await.unwrap();
            assert_eq!(
                a.image,
                b.image,
                "{task}: frames differ after {}",
                action.describe()
            );
            assert_eq!(local.shafts(), remote.shafts());
            assert_eq!(local.score(), remote.score());
        }
    }
}

/// Plays a fixed script of actions, then repeats the last one.
struct Scripted(Vec<Action>);

#[async_trait::async_trait]
impl Policy for Scripted {
    fn name(&self) -> String {
        "scripted".into()
    }

    async fn decide(&mut self, _: &Observation) -> Result<Decision, PolicyError> {
        let action = if self.0.len() > 1 {
            self.0.remove(0)
        } else {
            self.0[0].clone()
        };
        Ok(Decision::new(action))
    }
}

#[tokio::test]
async fn a_run_writes_its_transcript_and_rejections_spend_nothing() {
    let scenario = ScenarioFile::default();
    let dir = tempfile::tempdir().unwrap();
    let mut rig = SimRig::new(TaskKind::Cavity, &scenario, 0, MotorPath::InProcess)
        .await
        .unwrap();
    let mut aligned = aligning_actions(TaskKind::Cavity, &scenario, 0);
    let mut script = vec![
        Action::Cavity {
            command: [9000, 0],
            done: false,
        },
        Action::Cavity {
            command: [100, 100],
            done: false,
        },
    ];
    script.append(&mut aligned);
    let options = RunOptions {
        out_dir: Some(dir.path().to_owned()),
        seed: 0,
        ..RunOptions::default()
    };
    let summary = run_episode(
        &mut rig,
        &mut Scripted(script),
        None,
        &scenario.tasks,
        &options,
    )
    .await
    .unwrap();
    assert_eq!(
        summary.evaluations_used, 2,
        "the rejected command spent no evaluation"
    );
    assert_eq!(summary.rejected_actions, 1);
    assert!(summary.success && summary.declared_done);
    let transcript = std::fs::read_to_string(dir.path().join("transcript.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = transcript
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(
        lines.len(),
        1 + 1 + 3 + 1,
        "header, start, three steps, end"
    );
    assert!(
        lines[2]["rejected"]
            .as_str()
            .unwrap()
            .contains("x=9000 is outside [-8000, 8000]")
    );
    assert!(dir.path().join("frames/0002.png").exists());
    assert!(dir.path().join("summary.json").exists());
}

#[tokio::test]
async fn frames_come_at_the_asked_size_and_the_state_is_the_same() {
    let scenario = ScenarioFile::default();
    for (task, size) in [
        (TaskKind::Michelson, [160, 90]),
        (TaskKind::Cavity, [64, 51]),
        (TaskKind::Relay, [64, 48]),
    ] {
        let mut full = SimRig::new(task, &scenario, 5, MotorPath::InProcess)
            .await
            .unwrap();
        let mut small =
            SimRig::with_frame_size(task, &scenario, 5, MotorPath::InProcess, Some(size))
                .await
                .unwrap();
        let first = small.initial_image().await.unwrap();
        assert_eq!([first.width(), first.height()], size, "{task}");
        full.initial_image().await.unwrap();
        let action = aligning_actions(task, &scenario, 5).remove(0);
        let executed = small.execute(&action).await.unwrap();
        assert_eq!([executed.image.width(), executed.image.height()], size);
        full.execute(&action).await.unwrap();
        assert_eq!(
            small.score(),
            full.score(),
            "{task}: the hidden state is the same"
        );
    }
    let error = SimRig::with_frame_size(
        TaskKind::Cavity,
        &scenario,
        0,
        MotorPath::InProcess,
        Some([2000, 10]),
    )
    .await
    .err()
    .unwrap()
    .to_string();
    assert!(
        error.contains("does not fit the cavity camera of 1280x1024"),
        "{error}"
    );
}
