//! The rehearsal of docs/lab.md (section 7) through the binary, every step its own process
//! as on a bench: `optalign peer --scene michelson` is the whole bench (motors, and the
//! camera over HTTP) and writes a rig file with no calibration; `calibrate response` for
//! both mirrors and `calibrate backlash --write` succeed on it and write their results;
//! `run --policy vision` then aligns it and is scored through the calibration just made.
//! On a bench with a motor that is not wired, both calibrations refuse to save and say why.
//! The scene is docs/scenarios/binned.toml (480 x 270 px, the same field) to keep the test
//! quick.

use std::path::{Path, PathBuf};
use std::process::{Output, Stdio};
use std::time::Duration;

use optalign::lab::calibration::ResponseCalibration;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::{Child, Command};

use crate::BIN;
pub(crate) const KEY: &str = "rehearsal-test-key";
/// The default scene binned by 4: responses, beam radii and fringe period scaled by 1/4.
pub(crate) const SMALL_SCENE: &str = include_str!("../../../docs/scenarios/binned.toml");

/// A rehearsal peer in its own process, and the rig file it wrote.
pub(crate) struct Bench {
    pub(crate) peer: Child,
    pub(crate) rig: PathBuf,
}

async fn rehearsal_bench(dir: &Path, extra: &[&str]) -> Bench {
    rehearsal_bench_at(dir, 3, "0", extra).await
}

/// The rehearsal Michelson of `seed` on the small scene, its clock `time_scale` times real
/// time (0: instant), with `extra` arguments; its rig file is `dir/rig.toml`.
pub(crate) async fn rehearsal_bench_at(
    dir: &Path,
    seed: u64,
    time_scale: &str,
    extra: &[&str],
) -> Bench {
    let scenario = dir.join("small.toml");
    std::fs::write(&scenario, SMALL_SCENE).unwrap();
    let rig = dir.join("rig.toml");
    let mut peer = Command::new(BIN)
        .args(["peer", "--scene", "michelson", "--seed"])
        .arg(seed.to_string())
        .args(["--time-scale", time_scale])
        .args(["--listen", "127.0.0.1:0", "--camera-listen", "127.0.0.1:0"])
        .args(["--key", KEY, "--scenario"])
        .arg(&scenario)
        .arg("--write-rig")
        .arg(&rig)
        .args(extra)
        .env("RUST_LOG", "error")
        .stdout(Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(peer.stdout.take().unwrap()).lines();
    loop {
        let line = tokio::time::timeout(Duration::from_secs(20), lines.next_line())
            .await
            .expect("the peer starts")
            .unwrap()
            .expect("the peer writes its rig file");
        if line.starts_with("rig file: ") {
            break;
        }
    }
    Bench { peer, rig }
}

/// Runs `optalign ARGS` in `dir` as a user would, with the bench's key.
pub(crate) async fn optalign(dir: &Path, args: &[&str]) -> (Output, String) {
    let output = Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .env("OPTALIGN_KEY", KEY)
        .env("RUST_LOG", "error")
        .output()
        .await
        .unwrap();
    let printed = format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    );
    (output, printed)
}

/// Every element within 5 % of the response's size (its Frobenius norm).
fn assert_near(fitted: [[f64; 2]; 2], truth: [[f64; 2]; 2]) {
    let norm = truth.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    for row in 0..2 {
        for col in 0..2 {
            let error = (fitted[row][col] - truth[row][col]).abs();
            assert!(error <= 0.05 * norm, "{fitted:?} vs {truth:?}");
        }
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn the_documented_rehearsal_calibrates_and_aligns_a_michelson_across_processes() {
    let dir = tempfile::tempdir().unwrap();
    let bench = rehearsal_bench(dir.path(), &["--backlash", "30"]).await;
    let rig = bench.rig.to_str().unwrap();
    let calibration = dir.path().join("response-calibration.json");
    for mirror in ["1", "2"] {
        let (output, printed) = optalign(
            dir.path(),
            &["calibrate", "response", "--rig", rig, "--mirror", mirror],
        )
        .await;
        assert!(output.status.success(), "{printed}");
        assert!(
            printed.contains(&format!("wrote {}", calibration.display())),
            "{printed}"
        );
    }
    let written = ResponseCalibration::load(&calibration).unwrap();
    assert_eq!(written.image_size_px, [480, 270]);
    assert_near(
        written.mirror(1).unwrap().matrix_px_per_step,
        [[0.0425, 0.003], [-0.0025, -0.04]],
    );
    assert_near(
        written.mirror(2).unwrap().matrix_px_per_step,
        [[-0.04125, -0.00375], [0.003, 0.03875]],
    );

    let (output, printed) = optalign(
        dir.path(),
        &[
            "calibrate",
            "backlash",
            "--rig",
            rig,
            "--axis",
            "mirror_1_axis_1",
            "--amplitude",
            "200",
            "--step",
            "20",
            "--write",
        ],
    )
    .await;
    assert!(output.status.success(), "{printed}");
    let fitted: f64 = printed
        .split("backlash ")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|number| number.parse().ok())
        .unwrap_or_else(|| panic!("no fitted backlash in {printed}"));
    assert!((fitted - 30.0).abs() <= 4.0, "{printed}");
    assert!(
        printed.contains("wrote backlash") && printed.contains("saved it"),
        "{printed}"
    );

    let mut text = std::fs::read_to_string(&bench.rig).unwrap();
    text.push_str("\n[scoring]\nmichelson_calibration = \"response-calibration.json\"\n");
    std::fs::write(&bench.rig, text).unwrap();
    let (output, printed) = optalign(
        dir.path(),
        &[
            "run",
            "michelson",
            "--rig",
            rig,
            "--policy",
            "vision",
            "--out",
            "run",
        ],
    )
    .await;
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("rig.toml: aligned"), "{printed}");
    assert!(
        printed.contains("px") && printed.contains("response-calibration.json"),
        "the error has its unit and what it was measured from: {printed}"
    );
    assert!(!printed.contains("seed"), "{printed}");
}

#[tokio::test(flavor = "multi_thread")]
async fn an_axis_that_is_not_wired_is_refused_by_both_calibrations() {
    let dir = tempfile::tempdir().unwrap();
    // Axis 4 of the peer moves no mirror: mirror 1's second axis is wired to nothing.
    let bench = rehearsal_bench(dir.path(), &["--axes", "5"]).await;
    let text = std::fs::read_to_string(&bench.rig).unwrap().replace(
        "mirror_1_axis_2 = { controller = \"rehearsal\", axis = 1 }",
        "mirror_1_axis_2 = { controller = \"rehearsal\", axis = 4 }",
    );
    assert!(text.contains("axis = 4"), "{text}");
    std::fs::write(&bench.rig, text).unwrap();
    let rig = bench.rig.to_str().unwrap();

    let (output, printed) = optalign(
        dir.path(),
        &["calibrate", "response", "--rig", rig, "--mirror", "1"],
    )
    .await;
    assert_eq!(output.status.code(), Some(1), "{printed}");
    assert!(
        printed.contains("the tracked beam did not move with mirror_1_axis_2"),
        "{printed}"
    );
    assert!(printed.contains("nothing was saved"), "{printed}");
    assert!(!dir.path().join("response-calibration.json").exists());

    let (output, printed) = optalign(
        dir.path(),
        &[
            "calibrate",
            "backlash",
            "--rig",
            rig,
            "--axis",
            "mirror_1_axis_2",
            "--amplitude",
            "200",
            "--step",
            "20",
            "--write",
        ],
    )
    .await;
    assert_eq!(output.status.code(), Some(1), "{printed}");
    assert!(
        printed.contains("no beam moved when mirror_1_axis_2 moved by -200 steps"),
        "{printed}"
    );
    assert!(
        !printed.contains("wrote backlash") && !printed.contains("--write"),
        "{printed}"
    );
}
