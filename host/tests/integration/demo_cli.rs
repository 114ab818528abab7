//! `optalign demo`, the main job: the vision agent and a baseline on the three tasks over
//! the simulated peer, judged by the hidden true state each run recorded; the tables name
//! both policies with their intervals, the charts set them side by side, and only the runs
//! asked for keep their frames.

use std::path::Path;
use std::process::Command;

use crate::BIN;

/// The summary.json of one run of the demo's matrix.
fn summary(out: &Path, task: &str, policy: &str) -> serde_json::Value {
    let path = out.join(format!("runs/{task}-{policy}-seed0/summary.json"));
    serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap()
}

#[test]
fn the_demo_compares_the_vision_agent_with_a_baseline_on_every_task() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demo");
    let output = Command::new(BIN)
        .args(["demo", "--policies", "random,vision", "--seeds", "0"])
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{output:?}");
    for task in ["michelson", "cavity", "relay"] {
        assert!(printed.contains(&format!("## {task}")), "{printed}");
        let vision = summary(&out, task, "vision");
        assert_eq!(vision["success"], true, "{task}: {vision}");
        let random = summary(&out, task, "random");
        assert_eq!(random["policy"], "random");
        // One point per run in each speed-against-accuracy chart.
        assert!(
            out.join(format!("charts/speed_accuracy_{task}.png"))
                .is_file()
        );
        // Frames only where asked for (the vision runs, the default).
        assert!(
            out.join(format!("runs/{task}-vision-seed0/frames"))
                .is_dir()
        );
        assert!(
            !out.join(format!("runs/{task}-random-seed0/frames"))
                .exists()
        );
    }
    assert!(printed.contains("| vision | 1/1 (0.21–1.00)"), "{printed}");
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    assert!(report.contains("id=\"relay-vision-seed0\""), "{report}");
    assert!(report.contains("speed_accuracy_cavity.png"));
}

#[test]
fn a_filmstrip_of_a_policy_the_demo_does_not_run_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let output = Command::new(BIN)
        .args(["demo", "--policies", "random", "--filmstrips", "vision"])
        .arg("--out")
        .arg(dir.path())
        .output()
        .unwrap();
    assert_eq!(output.status.code(), Some(1), "{output:?}");
    let error = String::from_utf8_lossy(&output.stderr);
    assert!(error.contains("--filmstrips names \"vision\""), "{error}");
}
