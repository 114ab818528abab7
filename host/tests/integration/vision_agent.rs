//! The image-only "vision" policy: beam detection on rendered frames (sub-pixel centroids,
//! speckle against a spot, stationary artefacts cancelling in frame differences) and one
//! short end-to-end run per task, judged by the hidden truth.

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
    // Seeds 0 and 3 start with the beam at C3 as a large speckle cloud cut by the sensor's
    // edge, whose centroid misleads the first response fit; 9 is an ordinary start.
    for seed in [0, 3, 9] {
        let dir = tempfile::tempdir().unwrap();
        let summary = run_into(TaskKind::Relay, seed, Some(dir.path().to_path_buf())).await;
        assert!(
            summary.success && summary.declared_done,
            "seed {seed}: {summary:?}"
        );
        // The default mounts' backlash is compensated by the controller: no lost motion is
        // learned where there is none.
        let band = largest_lost_motion(&transcript_steps(dir.path()));
        assert!(band < 50.0, "seed {seed}: {band} steps of lost motion");
    }
}

#[tokio::test]
async fn the_relay_servo_does_not_probe_a_refuted_response_again_the_same_way() {
    // Seed 116: at C1 the spot sits whole by the sensor's edge and both probes from it took
    // it to the edge; the response they gave sent the servo back to the same tilt, which
    // refuted it, and the same two probes gave it again until the budget ran out.
    let summary = run_into(TaskKind::Relay, 116, None).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
}

#[tokio::test]
async fn the_relay_agent_takes_a_spot_that_no_tilt_moves_for_stray_light() {
    // Realistic seed 102: at C3 the beam went dark after a long tilt and the agent steered
    // by a stationary stray spot, growing its probes until they met the end of the range,
    // then sending tilts of zero steps to the end of the budget.
    let path =
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../docs/scenarios/realistic.toml");
    let scenario = ScenarioFile::load(&path).expect("the realistic scenario");
    let summary = run_on(TaskKind::Relay, 102, scenario, None).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
}

/// The widest dead band the relay agent claims to have learned on any axis, steps.
fn largest_lost_motion(steps: &[serde_json::Value]) -> f64 {
    let last = &steps.last().unwrap()["claims"]["lost_motion_steps"];
    last.as_array()
        .unwrap()
        .iter()
        .flat_map(|mirror| mirror.as_array().unwrap().iter())
        .map(|band| band.as_f64().unwrap())
        .fold(0.0, f64::max)
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
    for task in [TaskKind::Michelson, TaskKind::Cavity, TaskKind::Relay] {
        let summary = run_on(task, 4, scenario.clone(), None).await;
        assert!(
            summary.success && summary.declared_done,
            "{task}: {summary:?}"
        );
    }
}

#[tokio::test]
async fn the_vision_agent_aligns_the_relay_with_every_response_a_quarter_and_four_times_the_default()
 {
    // At four times the response the beam starts off the sensor at C1: the search grid is
    // sized from the brief's tilt per step and station distances, not from any constant.
    aligns_with_the_response_scaled(&[
        (TaskKind::Relay, 0.25, 1),
        (TaskKind::Relay, 4.0, 1),
        (TaskKind::Relay, 4.0, 6),
    ])
    .await;
}

/// Asserts that every `(task, sensitivity scale, seed)` run aligns and is declared done.
async fn aligns_with_the_response_scaled(runs: &[(TaskKind, f64, u64)]) {
    for &(task, scale, seed) in runs {
        let scenario = Knob::SensitivityScale
            .apply(&ScenarioFile::default(), scale)
            .expect("a valid scale");
        let summary = run_on(task, seed, scenario, None).await;
        assert!(
            summary.success && summary.declared_done,
            "{task} x{scale}, seed {seed}: {summary:?}"
        );
    }
}

#[tokio::test]
async fn the_vision_agent_aligns_the_michelson_and_the_cavity_at_a_quarter_and_four_times_the_response()
 {
    // Michelson x4: both beams start far off the sensor; seed 3 spent the budget before the
    // joint search and the tiled grid (seed 5 of 0..9 still does). Michelson x0.25: the
    // command range keeps both beams within a few radii of the centre; seed 5 starts with
    // them on top of each other and spent the budget steering the probed beam to the
    // centre, onto the other, until probes were steered clear of it within the reach of
    // the range. Cavity x4, seed 2: the secondary shows only in a patch of commands smaller
    // than the search's first grid, away from the start; it was found only once the search
    // covered the range with the centres of that grid's cells, and then only because a
    // secondary clear of the primary's core counts although it lies within the primary's
    // (halo-wide) second-moment radius. Seed 5: that search lands the secondary inside the
    // primary's saturated core; only the rim of it that shows beside the core tells the
    // agent to probe there rather than search on.
    aligns_with_the_response_scaled(&[
        (TaskKind::Michelson, 4.0, 3),
        (TaskKind::Michelson, 0.25, 2),
        (TaskKind::Michelson, 0.25, 5),
        (TaskKind::Cavity, 4.0, 3),
        (TaskKind::Cavity, 4.0, 2),
        (TaskKind::Cavity, 4.0, 5),
    ])
    .await;
}

#[tokio::test]
async fn the_vision_agent_aligns_the_relay_when_the_camera_lands_five_times_less_repeatably() {
    // Each placement of the camera is off by about 50 px: one image at C8 cannot tell where
    // the beam is to within the 50 px tolerance, so the agent averages as many placements as
    // the brief's repeatability calls for (seeds 0, 3 and 5 ended dark, 80 px and 117 px off
    // when it trusted one), and a spot lost at a far station is searched for there.
    let scenario = Knob::PlacementError
        .apply(&ScenarioFile::default(), 5.0)
        .expect("a valid scale");
    for seed in [0, 3, 5] {
        let summary = run_on(TaskKind::Relay, seed, scenario.clone(), None).await;
        assert!(
            summary.success && summary.declared_done,
            "seed {seed}: {summary:?}"
        );
    }
}

#[tokio::test]
async fn the_vision_agent_aligns_mounts_with_300_steps_of_uncompensated_backlash() {
    // The agent measures the dead band from reversals that moved the beam less than its
    // map predicted, and its commands take it up (without that, seven Michelson runs in ten
    // ended 50 to 65 px off). Cavity seed 3 is the one of its ten needing most evaluations.
    // The relay learns the band per mirror from its servo's reversals: seed 0 once spent its
    // budget probing again and again a spot the band held 20 px from the centre of C1.
    let scenario = Knob::Backlash
        .apply(&ScenarioFile::default(), 300.0)
        .expect("a valid backlash");
    for (task, seed) in [
        (TaskKind::Michelson, 2),
        (TaskKind::Michelson, 7),
        (TaskKind::Cavity, 3),
        (TaskKind::Relay, 0),
    ] {
        let dir = tempfile::tempdir().unwrap();
        let summary = run_on(task, seed, scenario.clone(), Some(dir.path().to_path_buf())).await;
        assert!(
            summary.success && summary.declared_done,
            "{task} seed {seed}: {summary:?}"
        );
        if task == TaskKind::Relay {
            // 300 steps of backlash less the controller's 30 of compensation: what the agent
            // learned is of that size, not more.
            let band = largest_lost_motion(&transcript_steps(dir.path()));
            assert!(
                (150.0..=350.0).contains(&band),
                "{band} steps of lost motion"
            );
        }
    }
}

#[tokio::test]
async fn the_vision_agent_aligns_the_michelson_with_beams_that_are_not_gaussian_or_not_alone() {
    // Each start once failed: a donut whose check found the wrong spot, a two-lobed beam
    // whose map sent the agent between one check and one relocation until the budget ran
    // out (seed 4), two-lobed beams probed onto each other (seed 8), a check that anchored its map on a stray spot taken for the beam, and a beam
    // that left the view from on top of a stray spot, measured with the spot as one.
    let base = ScenarioFile::default();
    let set = |knob: Knob, value: &str| {
        let value = knob.parse_value(value).expect("a known value");
        knob.apply(&base, value).expect("a valid scenario")
    };
    let donut = set(Knob::BeamProfile, "donut");
    let tem01 = set(Knob::BeamProfile, "tem01");
    let stray = set(Knob::StraySpots, "3");
    for (name, scenario, seed) in [
        ("donut", donut, 5),
        ("tem01", tem01.clone(), 4),
        ("tem01", tem01, 8),
        ("stray spots", stray.clone(), 6),
        ("stray spots", stray, 8),
    ] {
        let summary = run_on(TaskKind::Michelson, seed, scenario, None).await;
        assert!(
            summary.success && summary.declared_done,
            "{name}, seed {seed}: {summary:?}"
        );
    }
}

#[tokio::test]
async fn the_vision_agent_checks_again_when_a_refit_moves_where_the_final_command_puts_a_beam() {
    // Michelson at cross-coupling 0.8, seed 5: a check confirmed both maps, the map refitted
    // with that check's sightings turned mirror 2's response by about 20 degrees, and the
    // final command from it, sent with "done", left beam 2 112 px off.
    let scenario = Knob::CrossCoupling
        .apply(&ScenarioFile::default(), 0.8)
        .expect("a valid coupling");
    let summary = run_on(TaskKind::Michelson, 5, scenario, None).await;
    assert!(summary.success && summary.declared_done, "{summary:?}");
}
