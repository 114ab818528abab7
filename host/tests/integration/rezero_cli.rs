//! docs/lab.md's recovery from a power cut, through the binary against the rehearsal peer
//! (each step its own process, as on a bench): the responses are calibrated while the
//! positions are known; the peer process is killed in the middle of a move (its state
//! files keep the shafts and the flash, as a power cut does); started again, its moved
//! axes are `position-lost` and `run` refuses to start, naming `rezero`; `optalign rezero`
//! declares them within 20 steps of the true shafts; `run --policy vision` then aligns.
//! After a second cut, `run --rezero` re-references the bench and aligns it in one command.

use std::path::Path;
use std::time::Duration;

use optalign::scenario::ScenarioFile;
use optalign_firmware::sim::MountModel;
use optalign_optics::seeds::michelson_offsets;

use super::rehearsal::{Bench, KEY, SMALL_SCENE, optalign, rehearsal_bench_at};

const SEED: u64 = 5;

/// The true mirror positions the peer's mounts file holds.
fn shafts(state: &Path) -> Vec<i32> {
    let mut path = state.as_os_str().to_owned();
    path.push(".mounts.json");
    let text = std::fs::read(&path).unwrap();
    serde_json::from_slice::<Vec<MountModel>>(&text)
        .unwrap()
        .iter()
        .map(MountModel::mirror_position)
        .collect()
}

/// A peer on the bench's state files, its rig file scored through the calibration.
async fn peer(dir: &Path, time_scale: &str) -> Bench {
    let state = dir.join("peer.flash");
    let bench =
        rehearsal_bench_at(dir, SEED, time_scale, &["--state", state.to_str().unwrap()]).await;
    let mut text = std::fs::read_to_string(&bench.rig).unwrap();
    text.push_str("\n[scoring]\nmichelson_calibration = \"response-calibration.json\"\n");
    std::fs::write(&bench.rig, text).unwrap();
    bench
}

/// The controller URL the rig file names.
fn controller(rig: &Path) -> String {
    let text = std::fs::read_to_string(rig).unwrap();
    let line = text
        .lines()
        .find(|l| l.starts_with("url = \"tcp://"))
        .unwrap();
    line.trim_start_matches("url = \"")
        .trim_end_matches('"')
        .to_owned()
}

/// Kills `bench`'s peer process in the middle of moving by `deltas`, on a slow clock.
async fn cut_mid_move(dir: &Path, bench: Bench, deltas: &str) -> Vec<i32> {
    let state = dir.join("peer.flash");
    let mut bench = bench;
    bench.peer.kill().await.unwrap();
    let slow = peer(dir, "2").await;
    let before = shafts(&state);
    let url = controller(&slow.rig);
    let mut mover = tokio::process::Command::new(crate::BIN)
        .args(["move", "--controller", &url, "--relative"])
        .args(deltas.split(' '))
        .env("OPTALIGN_KEY", KEY)
        .env("RUST_LOG", "error")
        .kill_on_drop(true)
        .spawn()
        .unwrap();
    // Until the moving shafts are well on their way (half of 2400 steps), but not there.
    for _ in 0..2000 {
        let now = shafts(&state);
        if now.iter().zip(&before).any(|(a, b)| (a - b).abs() > 1200) {
            break;
        }
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    let mut slow = slow;
    slow.peer.kill().await.unwrap();
    let _ = mover.kill().await;
    let cut = shafts(&state);
    assert_ne!(cut, before, "the power went mid-move");
    cut
}

fn declared(printed: &str) -> Vec<(usize, i32, f64)> {
    let names = [
        "mirror_1_axis_1",
        "mirror_1_axis_2",
        "mirror_2_axis_1",
        "mirror_2_axis_2",
    ];
    printed
        .lines()
        .filter_map(|line| {
            let (name, rest) = line.split_once(": declared at ")?;
            let axis = names.iter().position(|n| *n == name)?;
            let mut words = rest.split_whitespace();
            let position = words.next()?.parse().ok()?;
            let sigma = rest
                .split("± ")
                .nth(1)?
                .split_whitespace()
                .next()?
                .parse()
                .ok()?;
            Some((axis, position, sigma))
        })
        .collect()
}

#[tokio::test(flavor = "multi_thread")]
async fn the_documented_recovery_from_a_power_cut_declares_the_lost_axes_and_aligns() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = dir.path().join("small.toml");
    std::fs::write(&scenario, SMALL_SCENE).unwrap();
    let o = michelson_offsets(&ScenarioFile::load(&scenario).unwrap().michelson, SEED);
    let bench = peer(dir.path(), "0").await;
    let rig = bench.rig.to_str().unwrap().to_owned();
    let url = controller(&bench.rig);
    // Both beams in view and apart, then both responses.
    let staged = [-o[0] - 1800, -o[1], -o[2] - 1800, -o[3]];
    let targets: Vec<String> = staged
        .iter()
        .enumerate()
        .map(|(axis, steps)| format!("{axis}={steps}"))
        .collect();
    let mut args = vec!["move", "--controller", url.as_str()];
    args.extend(targets.iter().map(String::as_str));
    let (output, printed) = optalign(dir.path(), &args).await;
    assert!(output.status.success(), "{printed}");
    for mirror in ["1", "2"] {
        let (output, printed) = optalign(
            dir.path(),
            &[
                "calibrate",
                "response",
                "--rig",
                &rig,
                "--mirror",
                mirror,
                "--span",
                "1000",
            ],
        )
        .await;
        assert!(output.status.success(), "{printed}");
    }

    cut_mid_move(dir.path(), bench, "0=2400 3=-1800").await;
    let bench = peer(dir.path(), "0").await;
    let rig = bench.rig.to_str().unwrap().to_owned();
    let (output, printed) = optalign(
        dir.path(),
        &[
            "run",
            "michelson",
            "--rig",
            &rig,
            "--policy",
            "vision",
            "--out",
            "run-1",
        ],
    )
    .await;
    assert_eq!(output.status.code(), Some(1), "{printed}");
    assert!(
        printed.contains("mirror_1_axis_1, mirror_2_axis_2")
            && printed.contains("optalign rezero --rig"),
        "{printed}"
    );

    let (output, printed) = optalign(dir.path(), &["rezero", "--rig", &rig]).await;
    assert!(output.status.success(), "{printed}");
    let found = declared(&printed);
    assert_eq!(
        found.iter().map(|f| f.0).collect::<Vec<_>>(),
        [0, 3],
        "{printed}"
    );
    let truth = shafts(&dir.path().join("peer.flash"));
    for (axis, position, sigma) in &found {
        let error = f64::from((position - truth[*axis]).abs());
        assert!(
            error <= 20.0 && error <= 3.0 * sigma + 0.5,
            "{printed}\ntruth {truth:?}"
        );
    }
    aligned_run(dir.path(), &rig, &["--out", "run-2"]).await;

    // The bench is aligned now, both beams on the centre: the cut moves them apart (a lost
    // axis that can only move its beam along the other beam is refused, see docs/lab.md).
    cut_mid_move(dir.path(), bench, "0=-2400 2=-1800").await;
    let bench = peer(dir.path(), "0").await;
    let rig = bench.rig.to_str().unwrap().to_owned();
    let printed = aligned_run(dir.path(), &rig, &["--out", "run-3", "--rezero"]).await;
    assert_eq!(
        declared(&printed).iter().map(|f| f.0).collect::<Vec<_>>(),
        [0, 2],
        "{printed}"
    );
}

/// `optalign run michelson --rig RIG --policy vision EXTRA`, which must align; what it said.
async fn aligned_run(dir: &Path, rig: &str, extra: &[&str]) -> String {
    let mut args = vec!["run", "michelson", "--rig", rig, "--policy", "vision"];
    args.extend(extra);
    let (output, printed) = optalign(dir, &args).await;
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("rig.toml: aligned"), "{printed}");
    printed
}
