//! The run loop's emergency stop from the monitor reaches the rig at once: while the policy
//! is still deciding, and while the rig is still executing a move. The run then ends with
//! the reason, the stop logged and the controllers' state recorded.

use std::future::pending;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use async_trait::async_trait;
use optalign::monitor::RunMonitor;
use optalign::policy::{Decision, Observation, Policy, PolicyError};
use optalign::rig::{ControllerView, Executed, Rig, Score};
use optalign::run::{RunOptions, run_episode};
use optalign::task::michelson::MichelsonScore;
use optalign::task::{Action, TaskKind, TaskLimits};
use optalign_optics::Frame;

/// A rig whose moves never end (a stalled mount), counting emergency stops.
struct StallingRig {
    emergency_stops: Arc<AtomicUsize>,
}

#[async_trait]
impl Rig for StallingRig {
    fn task(&self) -> TaskKind {
        TaskKind::Michelson
    }

    async fn initial_image(&mut self) -> anyhow::Result<Frame> {
        Ok(Frame::new(32, 24, vec![10; 32 * 24])?)
    }

    async fn execute(&mut self, _action: &Action) -> anyhow::Result<Executed> {
        pending().await
    }

    fn score(&self) -> Score {
        Score::Michelson(MichelsonScore {
            error_px: 40.0,
            commanded_error_px: 40.0,
            beam_centres_px: [[10.0, 12.0], [20.0, 12.0]],
        })
    }

    async fn emergency_stop(&mut self) -> anyhow::Result<()> {
        self.emergency_stops.fetch_add(1, Ordering::SeqCst);
        Ok(())
    }

    async fn controllers(&mut self) -> anyhow::Result<Vec<ControllerView>> {
        Ok(vec![ControllerView {
            name: "stalling".into(),
            emergency_stopped: self.emergency_stops.load(Ordering::SeqCst) > 0,
            axes: Vec::new(),
        }])
    }
}

/// A policy that moves at once, or (`thinking`) never makes up its mind.
struct Mover {
    thinking: bool,
}

#[async_trait]
impl Policy for Mover {
    fn name(&self) -> String {
        "mover".into()
    }

    async fn decide(&mut self, _observation: &Observation) -> Result<Decision, PolicyError> {
        if self.thinking {
            pending::<()>().await;
        }
        Ok(Decision::new(Action::Michelson {
            command: [100, 0, 0, 0],
            done: false,
        }))
    }
}

async fn stopped_run(thinking: bool) {
    let dir = tempfile::tempdir().unwrap();
    let emergency_stops = Arc::new(AtomicUsize::new(0));
    let mut rig = StallingRig {
        emergency_stops: emergency_stops.clone(),
    };
    let monitor = RunMonitor::new("stalled");
    let options = RunOptions {
        out_dir: Some(dir.path().to_owned()),
        monitor: Some(monitor.clone()),
        ..RunOptions::default()
    };
    let stopper = tokio::spawn(async move {
        tokio::time::sleep(Duration::from_millis(100)).await;
        monitor.request_stop("operator says stop").unwrap();
    });
    let summary = tokio::time::timeout(
        Duration::from_secs(10),
        run_episode(
            &mut rig,
            &mut Mover { thinking },
            None,
            &TaskLimits::default(),
            &options,
        ),
    )
    .await
    .expect("the stop ends the run")
    .unwrap();
    stopper.await.unwrap();
    assert_eq!(emergency_stops.load(Ordering::SeqCst), 1);
    assert_eq!(summary.failure.as_deref(), Some("operator says stop"));
    assert_eq!(summary.evaluations_used, 0);
    let written: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.path().join("summary.json")).unwrap()).unwrap();
    assert_eq!(written["failure"], "operator says stop");
    let transcript = std::fs::read_to_string(dir.path().join("transcript.jsonl")).unwrap();
    let stop = transcript
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|l| l["type"] == "stop")
        .expect("the stop is logged");
    assert_eq!(stop["reason"], "operator says stop");
    assert_eq!(stop["controllers"][0]["emergency_stopped"], true);
}

#[tokio::test]
async fn a_stop_reaches_the_rig_while_the_policy_is_still_deciding() {
    stopped_run(true).await;
}

#[tokio::test]
async fn a_stop_reaches_the_rig_while_a_move_is_still_running() {
    stopped_run(false).await;
}
