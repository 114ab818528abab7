//! Every number the command reads from a file, a flag or a pipe is bounded where it is
//! parsed: each family of out-of-range input gets an error naming the field and its range,
//! with exit code 1 (a run's error) or 2 (a command-line error), never a panic (101) or an
//! abort (134), and nothing is allocated for it first.

use std::path::Path;
use std::process::{Output, Stdio};

use optalign::peer::{PeerOptions, SimPeer, TimeMode};
use tokio::process::Command;

use crate::BIN;

async fn optalign(args: &[&str], dir: &Path) -> Output {
    Command::new(BIN)
        .args(args)
        .current_dir(dir)
        .env("RUST_LOG", "error")
        .stdin(Stdio::null())
        .output()
        .await
        .unwrap()
}

/// Asserts that the command failed with `code` and an error containing every one of
/// `names`, without a panic.
fn refused(output: &Output, code: i32, names: &[&str]) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(code), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for name in names {
        assert!(stderr.contains(name), "{name:?} not in: {stderr}");
    }
}

const MICHELSON_RIG: &str = r#"task = "michelson"
[[controller]]
name = "mounts"
url = "tcp://127.0.0.1:9"
[axes]
mirror_1_axis_1 = { controller = "mounts", axis = 0 }
mirror_1_axis_2 = { controller = "mounts", axis = 1 }
mirror_2_axis_1 = { controller = "mounts", axis = 2 }
mirror_2_axis_2 = { controller = "mounts", axis = 3 }
"#;

#[tokio::test]
async fn rig_file_times_out_of_range_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let cases = [
        (
            "[camera]\nkind = \"folder\"\npath = \".\"\n[settle]\nafter_motor_s = 1e308\n",
            "settle.after_motor_s: must be a time >= 0 s and at most 86400 s",
        ),
        (
            "[camera]\nkind = \"command\"\nargv = [\"true\", \"{output}\"]\ntimeout_s = 1e20\n",
            "camera.timeout_s: must be a time > 0 s and at most 86400 s",
        ),
    ];
    for (tail, error) in cases {
        std::fs::write(
            dir.path().join("rig.toml"),
            format!("{MICHELSON_RIG}{tail}"),
        )
        .unwrap();
        let output = optalign(
            &[
                "run",
                "michelson",
                "--rig",
                "rig.toml",
                "--policy",
                "vision",
            ],
            dir.path(),
        )
        .await;
        refused(&output, 1, &[error]);
    }
}

#[tokio::test]
async fn seed_lists_jobs_and_time_scales_are_bounded_on_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    for seeds in ["0..18446744073709551615", "0..1000000000"] {
        let output = optalign(&["bench", "--seeds", seeds], dir.path()).await;
        refused(&output, 2, &["--seeds", "more than 100000 seeds"]);
    }
    let output = optalign(&["bench", "--seeds", "0,0,0"], dir.path()).await;
    refused(&output, 2, &["seed 0 is named twice"]);
    let output = optalign(&["bench", "--jobs", "100000"], dir.path()).await;
    refused(&output, 2, &["--jobs", "(the cores)"]);
    let output = optalign(
        &["peer", "--listen", "127.0.0.1:0", "--time-scale", "1e-300"],
        dir.path(),
    )
    .await;
    refused(&output, 1, &["--time-scale: must be from 0.001 to 1000000"]);
    let output = optalign(&["status", "--controller", "tcp://[::1:5"], dir.path()).await;
    refused(&output, 2, &["malformed host"]);
    let output = optalign(
        &[
            "status",
            "--controller",
            "tcp://127.0.0.1:9",
            "--timeout-ms",
            "0",
        ],
        dir.path(),
    )
    .await;
    refused(&output, 2, &["--timeout-ms"]);
}

#[tokio::test]
async fn scenario_frames_too_large_to_render_are_refused_before_rendering() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("huge.toml"),
        "[michelson]\nwidth_px = 16384\nheight_px = 16384\n",
    )
    .unwrap();
    let output = optalign(
        &[
            "render",
            "michelson",
            "--scenario",
            "huge.toml",
            "--out",
            "f.png",
        ],
        dir.path(),
    )
    .await;
    refused(&output, 1, &["michelson.width_px", "at most 25000000"]);
}

#[tokio::test]
async fn a_closed_standard_output_ends_the_command_quietly() {
    let options = PeerOptions {
        time: TimeMode::Instant,
        ..PeerOptions::default()
    };
    let (_peer, address) = SimPeer::start_on_loopback(&options).await.unwrap();
    let controller = format!("tcp://{address}");
    for json in [false, true] {
        let mut command = Command::new(BIN);
        command
            .args(["status", "--controller", &controller])
            .stdout(Stdio::piped())
            .stderr(Stdio::piped());
        if json {
            command.arg("--json");
        }
        let mut child = command.spawn().unwrap();
        // The reader goes away before the first line (`optalign status | head -0`).
        drop(child.stdout.take());
        let output = child.wait_with_output().await.unwrap();
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(0), "{stderr}");
        assert!(stderr.is_empty(), "{stderr}");
    }
}
