//! The image-only "vision" policy: beam detection on rendered frames (sub-pixel centroids,
//! speckle against a spot, stationary artefacts cancelling in frame differences) and short
//! end-to-end runs, judged by the hidden truth: one per task with its claims checked, another
//! camera, and the relay through uncompensated backlash.
//!
//! Success rates belong to the bench, not here: the starts that once failed (responses a
//! quarter and four times the default, uncompensated backlash on the Michelson and the
//! cavity, donut, TEM01 and stray-spot beams, cross-coupling 0.8, a camera placed five times
//! less repeatably, the relay's refuted responses) are cells of the stability map in
//! docs/results.md, run on many seeds by `optalign bench --policies vision --sweep ...`.

use optalign::imaging::{Picture, changes, find_beams};
use std::sync::Arc;

use optalign::bench::{Knob, MatrixOptions, RunSpec, run_one};
use optalign::scenario::ScenarioFile;
use optalign::task::TaskKind;
use optalign_optics::{CameraPose, Cavity, Michelson, Relay, Station};

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[test]
fn a_clean_michelson_beam_is_found_within_a_pixel() {
    let scene = Michelson::new(ScenarioFile::default().michelson, [0; 4]).unwrap();
    let shaft = [700, -400, 20_000, 0];
    let beams = find_beams(&Picture::new(&scene.render(&shaft, 3)));
    assert_eq!(beams.len(), 1, "{beams:?}");
    let truth = scene.truth(&shaft).beam_centres_px[0];
    assert!(
        distance(beams[0].centre, truth) < 1.0,
        "{beams:?} vs {truth:?}"
    );
    assert!(beams[0].localised && !beams[0].clipped);
}

#[test]
fn a_michelson_beam_cut_by_the_border_is_flagged_and_its_centre_fitted() {
    let scene = Michelson::new(ScenarioFile::default().michelson, [0; 4]).unwrap();
    // Mirror 1's beam from inside the top edge to 100 px beyond it; mirror 2's far away.
    for vertical in [3000, 3500, 4000] {
        let shaft = [-2000, vertical, 20_000, 0];
        let truth = scene.truth(&shaft).beam_centres_px[0];
        let beams = find_beams(&Picture::new(&scene.render(&shaft, 5)));
        assert_eq!(beams.len(), 1, "{beams:?}");
        let fit = beams[0].fit.expect("a spot fit");
        assert!(beams[0].clipped, "{beams:?}");
        assert!(distance(fit.centre, truth) < 3.0, "{fit:?} vs {truth:?}");
        assert!(
            distance(beams[0].centre, truth) > 10.0,
            "the centroid is pulled inwards"
        );
    }
}

#[test]
fn a_relay_spot_is_localised_and_a_clipped_beam_is_speckle() {
    let scene = Relay::new(ScenarioFile::default().relay, [0; 8]).unwrap();
    let spot = find_beams(&Picture::new(&scene.render(
        &[0; 8],
        &CameraPose::nominal(Station::C8),
        1,
    )));
    assert!(spot[0].localised, "{spot:?}");
    assert!(distance(spot[0].centre, [320.0, 240.0]) < 1.0, "{spot:?}");
    // Tilted so that half the beam misses C2's sensor (3.2 mm at 254.4 mm from M1).
    let halfway = [1300, -1300].map(|steps| {
        let mut shaft = [0; 8];
        shaft[1] = steps;
        find_beams(&Picture::new(&scene.render(
            &shaft,
            &CameraPose::nominal(Station::C2),
            1,
        )))
    });
    assert!(
        halfway
            .iter()
            .all(|beams| !beams.is_empty() && !beams[0].localised),
        "{halfway:?}"
    );
}

#[test]
fn cavity_artefacts_cancel_and_the_secondary_shows_in_the_difference() {
    let scene = Cavity::new(ScenarioFile::default().cavity, [0; 2]).unwrap();
    let (a, b) = ([2000, 1500], [-1500, 1500]);
    let moved = changes(
        &Picture::new(&scene.render(&a, 1)),
        &Picture::new(&scene.render(&b, 2)),
    );
    assert_eq!(moved.appeared.len(), 1, "{moved:?}");
    assert_eq!(moved.vanished.len(), 1, "{moved:?}");
    let truth = |shaft: &[i32]| scene.truth(shaft).secondary_centre_px;
    assert!(
        distance(moved.appeared[0].centre, truth(&b)) < 2.0,
        "{moved:?}"
    );
    assert!(
        distance(moved.vanished[0].centre, truth(&a)) < 2.0,
        "{moved:?}"
    );
}

/// One run of the vision agent on the default scenario, through the bench's own runner.
async fn run_into(
    task: TaskKind,
    seed: u64,
    out_dir: Option<std::path::PathBuf>,
) -> optalign::run::RunSummary {
    run_on(task, seed, ScenarioFile::default(), out_dir).await
}

/// One run of the vision agent on `scenario`, through the bench's own runner.
async fn run_on(
    task: TaskKind,
    seed: u64,
    scenario: ScenarioFile,
    out_dir: Option<std::path::PathBuf>,
) -> optalign::run::RunSummary {
    let spec = RunSpec {
        task,
        policy: "vision".into(),
        seed,
        scenario: Arc::new(scenario),
        setting: None,
        out_dir,
    };
    run_one(&spec, &MatrixOptions::default())
        .await
        .unwrap()
        .summary
}

#[tokio::test]
async fn the_vision_agent_aligns_the_michelson_and_its_claims_match_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let summary = run_into(TaskKind::Michelson, 6, Some(dir.path().to_path_buf())).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
    assert!(summary.terminal_error.unwrap() < 10.0, "{summary:?}");
    assert!(summary.evaluations_used <= 12, "{summary:?}");
    let steps = transcript_steps(dir.path());
    // Where the agent says the beams end up, judged against the hidden beam centres.
    let last = steps.last().unwrap();
    for k in 0..2 {
        let claimed = point(&last["claims"]["mirrors"][k]["predicted_px"]);
        let truth = point(&last["score"]["beam_centres_px"][k]);
        assert!(
            distance(claimed, truth) < 3.0,
            "mirror {k}: {claimed:?} vs {truth:?}"
        );
    }
}

/// The step entries of a run's transcript; every one carries the agent's claims.
fn transcript_steps(dir: &std::path::Path) -> Vec<serde_json::Value> {
    let transcript = std::fs::read_to_string(dir.join("transcript.jsonl")).unwrap();
    let steps: Vec<serde_json::Value> = transcript
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .filter(|entry: &serde_json::Value| entry["type"] == "step")
        .collect();
    assert!(steps.iter().all(|step| step["claims"]["phase"].is_string()));
    steps
}

/// A JSON `[x, y]` as a point (NaN where missing).
fn point(value: &serde_json::Value) -> [f64; 2] {
    [&value[0], &value[1]].map(|v| v.as_f64().unwrap_or(f64::NAN))
}

#[tokio::test]
async fn the_vision_agent_aligns_the_cavity_and_its_claims_match_the_truth() {
    let dir = tempfile::tempdir().unwrap();
    let summary = run_into(TaskKind::Cavity, 0, Some(dir.path().to_path_buf())).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
    let steps = transcript_steps(dir.path());
    let last = steps.last().unwrap();
    let claimed = point(&last["claims"]["secondary"]["predicted_px"]);
    let truth = point(&last["score"]["secondary_centre_px"]);
    assert!(distance(claimed, truth) < 3.0, "{claimed:?} vs {truth:?}");
}

#[tokio::test]
async fn the_vision_agent_aligns_the_relay() {
    // Seed 3 starts with the beam at C3 as a large speckle cloud cut by the sensor's edge,
    // whose centroid misleads the first response fit.
    let summary = run_into(TaskKind::Relay, 3, None).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
}

#[tokio::test]
async fn the_vision_agent_aligns_every_task_on_a_1280_by_720_camera() {
    // Nothing about the default cameras (1920 x 1080, 1280 x 1024, 640 x 480) is built in:
    // the same agent learns this camera's scales from its images.
    let mut scenario = ScenarioFile::default();
    (scenario.michelson.width_px, scenario.michelson.height_px) = (1280, 720);
    (scenario.cavity.width_px, scenario.cavity.height_px) = (1280, 720);
    (
        scenario.relay.camera.width_px,
        scenario.relay.camera.height_px,
    ) = (1280, 720);
    for task in [TaskKind::Michelson, TaskKind::Cavity] {
        let summary = run_on(task, 4, scenario.clone(), None).await;
        assert!(
            summary.success && summary.declared_done,
            "{task}: {summary:?}"
        );
    }
}

#[tokio::test]
async fn the_relay_agent_aligns_through_300_steps_of_uncompensated_backlash() {
    // The relay models no dead band: a step that a reversal leaves short is absorbed by the
    // servo's trust region (seed 0 once spent its budget probing again and again a spot the
    // band held 20 px from the centre of C1).
    let scenario = Knob::Backlash
        .apply(&ScenarioFile::default(), 300.0)
        .expect("a valid backlash");
    let summary = run_on(TaskKind::Relay, 0, scenario, None).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
}

#[tokio::test]
async fn a_run_the_agent_is_never_sure_of_ends_by_its_budget_not_declared_done() {
    // At artefact brightness 6 the cavity's checks beside the primary never make it sure
    // (docs/results.md): it sends the secondary to the target with the budget all but spent
    // and leaves it there, aligned by the hidden truth, without claiming to be done.
    let scenario = Knob::ArtefactBrightness
        .apply(&ScenarioFile::default(), 6.0)
        .expect("a valid artefact brightness");
    let budget = scenario.tasks.budget(TaskKind::Cavity);
    let summary = run_on(TaskKind::Cavity, 0, scenario, None).await;
    assert!(summary.success && !summary.declared_done, "{summary:?}");
    assert_eq!(summary.evaluations_used, budget, "{summary:?}");
}
