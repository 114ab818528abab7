//! The lab-rig code path end to end without hardware: rig files that point at simulated
//! peers over loopback TCP and the simulated camera (and camera mover) run all three tasks
//! with the vision agent, and calibration from the camera recovers the simulated mounts'
//! true backlash and the scene's true sensitivities within 10 %.

use std::path::Path;
use std::sync::Arc;

use optalign::lab::calibrate::{calibrate_backlash, calibrate_response};
use optalign::lab::calibration::{MirrorResponse, ResponseCalibration};
use optalign::lab::{LabRig, RigFile};
use optalign::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};
use optalign::policy::{PolicyOptions, TaskBrief, build_policy};
use optalign::run::{RunOptions, run_episode};
use optalign::scenario::ScenarioFile;
use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{Cavity, Michelson, Relay};

const KEY: &str = "lab-rig-test-key";

async fn peer(axes: u8, backlash: u32) -> (Arc<SimPeer>, String) {
    let options = PeerOptions {
        axes,
        mechanics: MechanicsOptions {
            backlash,
            ..MechanicsOptions::default()
        },
        key: Some(KEY.into()),
        state_file: None,
        time: TimeMode::Instant,
        ..PeerOptions::default()
    };
    let (peer, address) = SimPeer::start_on_loopback(&options).await.unwrap();
    (peer, format!("tcp://{address}"))
}

fn rig_file(text: &str, dir: &Path) -> RigFile {
    // SAFETY: tests in this binary all use the same key value.
    unsafe { std::env::set_var("OPTALIGN_LAB_KEY", KEY) };
    RigFile::parse(text, dir).unwrap()
}

/// docs/scenarios/binned.toml: the default scene through a camera binned to 480 x 270 px,
/// quick to render and analyse (the cavity and the relay keep their default cameras).
fn binned_scenario_path() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/scenarios/binned.toml")
}

fn binned_scenario() -> ScenarioFile {
    ScenarioFile::load(&binned_scenario_path()).expect("docs/scenarios/binned.toml")
}

/// The rig-file tables of the simulated camera for `seed` on the binned scene, with no
/// settling waits.
fn instant_sim_camera(seed: u64) -> String {
    format!(
        r#"[camera]
kind = "sim"
seed = {seed}
scenario = "{}"
[settle]
after_motor_s = 0
after_camera_s = 0
"#,
        binned_scenario_path().display()
    )
}

/// A client holding the peers' access key.
async fn keyed_client(url: &str) -> optalign::link::Client {
    optalign::link::Client::connect(
        url.parse().unwrap(),
        optalign::link::ClientOptions {
            key: Some(optalign::link::AccessKey::passphrase(KEY)),
            ..Default::default()
        },
    )
    .await
    .unwrap()
}

/// Compensation equal to the true dead band, as after `optalign calibrate backlash --write`.
/// A keyed client that controls the peer: a client dropped just before may hold control
/// until the peer notices it left, so the first controlling request is retried while the
/// peer answers busy.
async fn controlling_client(url: &str) -> optalign::link::Client {
    let client = keyed_client(url).await;
    for _ in 0..100 {
        let config = client.get_config(0).await.unwrap();
        match client
            .command_ok(optalign_protocol::Command::SetConfig { axis: 0, config })
            .await
        {
            Err(e) if e.code() == Some(optalign_protocol::ErrorCode::BUSY) => {
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            }
            other => {
                other.unwrap();
                return client;
            }
        }
    }
    panic!("the peer never released control");
}

async fn compensate(url: &str, axes: u8, backlash: u16) {
    let client = controlling_client(url).await;
    for axis in 0..axes {
        let mut config = client.get_config(axis).await.unwrap();
        config.backlash = backlash;
        config.backlash_mode = optalign_protocol::BacklashMode::OneSided;
        client
            .command_ok(optalign_protocol::Command::SetConfig { axis, config })
            .await
            .unwrap();
    }
}

async fn run_vision(rig: RigFile) -> optalign::run::RunSummary {
    let limits = rig.limits.clone();
    let task = rig.task;
    let rig_geometry = rig.geometry.clone();
    let mut bench = LabRig::connect(rig).await.unwrap();
    let brief = TaskBrief::new(task, &limits, rig_geometry);
    let mut built = build_policy("vision", &brief, &PolicyOptions::default()).unwrap();
    let options = RunOptions {
        out_dir: None,
        ..RunOptions::default()
    };
    run_episode(&mut bench, built.policy.as_mut(), None, &limits, &options)
        .await
        .unwrap()
}

#[tokio::test(flavor = "multi_thread")]
async fn michelson_runs_through_the_lab_rig_and_is_scored_by_calibration() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = binned_scenario();
    let seed = 2;
    let offsets = michelson_offsets(&scenario.michelson, seed);
    let (peer, url) = peer(4, 30).await;
    compensate(&url, 4, 30).await;
    // The calibration a bench would have measured: the scene's true response.
    let p = &scenario.michelson;
    let centre = [f64::from(p.width_px) / 2.0, f64::from(p.height_px) / 2.0];
    let mirror = |m: usize, matrix: [[f64; 2]; 2]| MirrorResponse {
        mirror: m,
        axes: [format!("mirror_{m}_axis_1"), format!("mirror_{m}_axis_2")],
        axis_indices: [2 * m - 2, 2 * m - 1],
        reference_steps: [
            -f64::from(offsets[2 * m - 2]),
            -f64::from(offsets[2 * m - 1]),
        ],
        centre_px: centre,
        matrix_px_per_step: matrix,
        residual_rms_px: 0.0,
        points: 0,
        stationary_px: None,
    };
    let calibration = ResponseCalibration {
        image_size_px: [p.width_px, p.height_px],
        mirrors: vec![
            mirror(1, p.mirror_1_sensitivity_px_per_step),
            mirror(2, p.mirror_2_sensitivity_px_per_step),
        ],
    };
    calibration
        .save(&dir.path().join("calibration.json"))
        .unwrap();
    let rig = rig_file(
        &format!(
            "{}[scoring]\nmichelson_calibration = \"calibration.json\"\n",
            michelson_bench(&url, seed)
        ),
        dir.path(),
    );
    let summary = run_vision(rig).await;
    let truth = Michelson::new(scenario.michelson.clone(), offsets)
        .unwrap()
        .truth(&peer.shaft_positions());
    assert!(truth.error_px < 20.0, "true error {} px", truth.error_px);
    let scored = summary.terminal_error.unwrap();
    assert!(
        (scored - truth.error_px).abs() < 5.0,
        "lab score {scored} vs truth {}",
        truth.error_px
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn cavity_runs_through_the_lab_rig_with_remapped_axes() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = binned_scenario();
    let seed = 4;
    let offsets = cavity_offsets(&scenario.cavity, seed);
    let (peer, url) = peer(4, 30).await;
    compensate(&url, 4, 30).await;
    // x is motor 3, y is motor 1, as on the paper's bench.
    let rig = rig_file(
        &format!(
            r#"
task = "cavity"
[[controller]]
name = "incoupler"
url = "{url}"
key_env = "OPTALIGN_LAB_KEY"
[axes]
x = {{ controller = "incoupler", axis = 3 }}
y = {{ controller = "incoupler", axis = 1 }}
{camera}[scoring]
cavity_aligned = [{}, {}]
"#,
            -offsets[0],
            -offsets[1],
            camera = instant_sim_camera(seed),
        ),
        dir.path(),
    );
    let summary = run_vision(rig).await;
    let shafts = peer.shaft_positions();
    let truth = Cavity::new(scenario.cavity.clone(), offsets)
        .unwrap()
        .truth(&[shafts[3], shafts[1]]);
    assert!(truth.success, "true error {} steps", truth.error_steps);
    assert!(
        summary.success,
        "the bench score agrees: {:?}",
        summary.terminal_error
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn relay_runs_through_the_lab_rig_over_two_controllers_and_the_camera_mover() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = binned_scenario();
    let seed = 9;
    let offsets = relay_offsets(&scenario.relay, seed).unwrap();
    let (peer_a, url_a) = peer(4, 30).await;
    let (peer_b, url_b) = peer(4, 30).await;
    compensate(&url_a, 4, 30).await;
    compensate(&url_b, 4, 30).await;
    let rig = rig_file(
        &format!(
            r#"
task = "relay"
[[controller]]
name = "a"
url = "{url_a}"
key_env = "OPTALIGN_LAB_KEY"
[[controller]]
name = "b"
url = "{url_b}"
key_env = "OPTALIGN_LAB_KEY"
[axes]
m1v = {{ controller = "a", axis = 0 }}
m1h = {{ controller = "a", axis = 1 }}
m2v = {{ controller = "a", axis = 2 }}
m2h = {{ controller = "a", axis = 3 }}
m3v = {{ controller = "b", axis = 0 }}
m3h = {{ controller = "b", axis = 1 }}
m4v = {{ controller = "b", axis = 2 }}
m4h = {{ controller = "b", axis = 3 }}
{camera}[mover]
kind = "sim"
[geometry]
sensor_mm = [6.4, 4.8]
image_px = [640, 480]
tilt_rad_per_step = 6.5918e-6
station_distances_mm = [25.0, 254.4, 25.0, 178.2, 25.0, 254.4, 25.0, 300.0]
"#,
            camera = instant_sim_camera(seed),
        ),
        dir.path(),
    );
    let summary = run_vision(rig).await;
    let shafts: Vec<i32> = peer_a
        .shaft_positions()
        .into_iter()
        .chain(peer_b.shaft_positions())
        .collect();
    let truth = Relay::new(scenario.relay.clone(), offsets)
        .unwrap()
        .truth(&shafts);
    let [x, y] = truth.c8_offset_px.expect("light reaches C8");
    assert!(
        truth.mirrors.iter().all(|m| m.reached() && !m.clipped()) && x.hypot(y) < 50.0,
        "C8 offset {x} {y}"
    );
    assert!(
        summary.success,
        "the bench's own score sees the centred spot at C8"
    );
}

fn michelson_bench(url: &str, seed: u64) -> String {
    format!(
        r#"
task = "michelson"
[[controller]]
name = "mounts"
url = "{url}"
key_env = "OPTALIGN_LAB_KEY"
[axes]
mirror_1_axis_1 = {{ controller = "mounts", axis = 0 }}
mirror_1_axis_2 = {{ controller = "mounts", axis = 1 }}
mirror_2_axis_1 = {{ controller = "mounts", axis = 2 }}
mirror_2_axis_2 = {{ controller = "mounts", axis = 3 }}
{camera}"#,
        camera = instant_sim_camera(seed),
    )
}

/// Moves the simulated mounts so mirror 1's beam is centred and mirror 2's is off-screen.
async fn stage_michelson(url: &str, offsets: [i32; 4]) {
    let client = controlling_client(url).await;
    let targets = [-offsets[0], -offsets[1], -offsets[2] + 9000, -offsets[3]];
    let values: Vec<optalign_protocol::AxisValue> = targets
        .iter()
        .enumerate()
        .map(|(axis, &steps)| optalign_protocol::AxisValue {
            axis: axis as u8,
            steps,
        })
        .collect();
    client.move_to(&values).await.unwrap();
}

#[tokio::test(flavor = "multi_thread")]
async fn response_calibration_recovers_the_true_sensitivity_within_ten_percent() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = binned_scenario();
    let seed = 3;
    let offsets = michelson_offsets(&scenario.michelson, seed);
    let (_peer, url) = peer(4, 30).await;
    compensate(&url, 4, 30).await;
    stage_michelson(&url, offsets).await;
    let rig = rig_file(&michelson_bench(&url, seed), dir.path());
    let mut bench = LabRig::connect_unscored(rig).await.unwrap();
    let scan = calibrate_response(&mut bench, 1, 1200, 3).await.unwrap();
    assert_eq!(scan.points.len(), 9);
    assert!(scan.doubts.is_empty(), "{:?}", scan.doubts);
    let response = scan.response;
    let truth = scenario.michelson.mirror_1_sensitivity_px_per_step;
    let norm = truth.iter().flatten().map(|v| v * v).sum::<f64>().sqrt();
    for (row, (fitted, exact)) in response.matrix_px_per_step.iter().zip(&truth).enumerate() {
        for col in 0..2 {
            let error = (fitted[col] - exact[col]).abs();
            assert!(
                error <= 0.1 * exact[col].abs().max(0.1 * norm),
                "[{row}][{col}]: {} vs {}",
                fitted[col],
                exact[col]
            );
        }
    }
    assert!(
        response.residual_rms_px < 2.0,
        "{}",
        response.residual_rms_px
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn backlash_calibration_recovers_the_true_dead_band_within_ten_percent() {
    let dir = tempfile::tempdir().unwrap();
    let scenario = binned_scenario();
    let seed = 3;
    let offsets = michelson_offsets(&scenario.michelson, seed);
    let (_peer, url) = peer(4, 40).await;
    compensate(&url, 4, 40).await;
    stage_michelson(&url, offsets).await;
    let rig = rig_file(&michelson_bench(&url, seed), dir.path());
    let mut bench = LabRig::connect_unscored(rig).await.unwrap();
    let report = calibrate_backlash(&mut bench, 0, 300, 10).await.unwrap();
    assert!(
        (report.fit.backlash - 40.0).abs() <= 4.0,
        "{:?}",
        report.fit
    );
    assert!(report.fit.uncertainty <= 4.0, "{:?}", report.fit);
    assert!(report.doubts.is_empty(), "{:?}", report.doubts);
    // The axis's compensation is restored after the scan.
    let (client, axis) = bench.controller_axis(0);
    assert_eq!(
        client.get_config(axis).await.unwrap().backlash_mode,
        optalign_protocol::BacklashMode::OneSided
    );
}

#[tokio::test(flavor = "multi_thread")]
async fn bad_rig_files_and_unreachable_benches_fail_before_anything_moves() {
    let dir = tempfile::tempdir().unwrap();
    let error = RigFile::parse("task = \"cavity\"\n[[controller]]\nname = \"a\"\nurl = \"tcp://127.0.0.1:1\"\n[axes]\nx = { controller = \"a\", axis = 3 }\n[camera]\nkind = \"sim\"\n", dir.path())
        .unwrap_err();
    assert!(
        format!("{error:#}").contains("axes.y: missing"),
        "{error:#}"
    );
    let error = RigFile::parse("task = \"cavity\"\n[[controller]]\nname = \"a\"\nurl = \"127.0.0.1:1\"\n[axes]\n[camera]\nkind = \"sim\"\n", dir.path()).unwrap_err();
    assert!(
        format!("{error:#}").contains("controller[0].url"),
        "{error:#}"
    );
    let error = RigFile::parse("task = \"relay\"\nbogus = 1\n", dir.path()).unwrap_err();
    assert!(format!("{error:#}").contains("bogus"), "{error:#}");
    let rig = rig_file(
        "task = \"cavity\"\n[[controller]]\nname = \"a\"\nurl = \"tcp://127.0.0.1:1\"\nkey_env = \"OPTALIGN_LAB_KEY\"\n[axes]\nx = { controller = \"a\", axis = 3 }\ny = { controller = \"a\", axis = 1 }\n[camera]\nkind = \"sim\"\n[scoring]\ncavity_aligned = [0, 0]\n",
        dir.path(),
    );
    let error = LabRig::connect(rig).await.err().unwrap();
    assert!(
        format!("{error:#}").contains("unreachable; nothing was moved"),
        "{error:#}"
    );
}

#[test]
fn the_documented_example_rig_files_are_valid() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/rigs");
    for task in ["michelson", "cavity", "relay"] {
        let path = dir.join(format!("{task}.toml"));
        let rig = RigFile::load(&path).unwrap_or_else(|e| panic!("{}: {e:#}", path.display()));
        assert_eq!(rig.task.name(), task);
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn a_run_whose_camera_stops_answering_ends_on_record_and_exits_non_zero() {
    const BIN: &str = env!("CARGO_BIN_EXE_optalign");
    let dir = tempfile::tempdir().unwrap();
    let (_peer, url) = peer(4, 0).await;
    let first = dir.path().join("first.png");
    let rendered = tokio::process::Command::new(BIN)
        .args(["render", "cavity", "--seed", "0", "--out"])
        .arg(&first)
        .output()
        .await
        .unwrap();
    assert!(rendered.status.success(), "{rendered:?}");
    // The camera gives two frames (the rig's check at connect and the run's first), then
    // hangs: a USB camera that stopped answering.
    let script = dir.path().join("camera.sh");
    std::fs::write(
        &script,
        format!(
            "if [ -e {taken}2 ]; then exec sleep 30; fi\n\
             if [ -e {taken}1 ]; then touch {taken}2; else touch {taken}1; fi\n\
             cp {first} \"$1\"\n",
            taken = dir.path().join("taken").display(),
            first = first.display()
        ),
    )
    .unwrap();
    let rig = dir.path().join("rig.toml");
    std::fs::write(
        &rig,
        format!(
            r#"task = "cavity"
[[controller]]
name = "incoupler"
url = "{url}"
key_env = "OPTALIGN_LAB_KEY"
[axes]
x = {{ controller = "incoupler", axis = 0 }}
y = {{ controller = "incoupler", axis = 1 }}
[camera]
kind = "command"
argv = ["sh", "{}", "{{output}}"]
timeout_s = 1
[settle]
after_motor_s = 0
after_camera_s = 0
[scoring]
cavity_aligned = [0, 0]
"#,
            script.display()
        ),
    )
    .unwrap();
    let out = dir.path().join("run");
    let output = tokio::process::Command::new(BIN)
        .args(["run", "cavity", "--policy", "vision", "--rig"])
        .arg(&rig)
        .arg("--out")
        .arg(&out)
        .env("OPTALIGN_LAB_KEY", KEY)
        .env("RUST_LOG", "error")
        .output()
        .await
        .unwrap();
    let printed = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{printed}");
    assert!(printed.contains("did not finish within 1s"), "{printed}");
    let transcript = std::fs::read_to_string(out.join("transcript.jsonl")).unwrap();
    let kinds: Vec<String> = transcript
        .lines()
        .map(|line| serde_json::from_str::<serde_json::Value>(line).unwrap()["type"].to_string())
        .collect();
    // The first frame came, the first move ran, its frame never did.
    assert_eq!(kinds[..2], ["\"run\"", "\"start\""]);
    assert_eq!(kinds[kinds.len() - 2..], ["\"failure\"", "\"end\""]);
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["ended_by"], "rig");
    assert!(
        summary["failure"]
            .as_str()
            .unwrap()
            .contains("camera command \"sh\" did not finish within 1s"),
        "{summary}"
    );
}
