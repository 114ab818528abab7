//! The bench on tiny matrices: it writes results.csv, summary.md, PNG and SVG charts and
//! per-run transcripts; a sweep writes one row per knob value and its chart, several
//! sweeps one stability map per task; the demo's HTML report shows each frame as a
//! thumbnail with its action.

use std::path::Path;
use std::sync::Arc;

use indicatif::ProgressBar;
use optalign::bench::report::{THUMBNAIL_WIDTH, write_report};
use optalign::bench::results::success_cell;
use optalign::bench::{
    BenchPlan, Knob, MatrixOptions, SavedFrames, SweepSpec, matrix, run_bench, run_matrix,
};
use optalign::rig::MotorPath;
use optalign::scenario::ScenarioFile;
use optalign::task::TaskKind;

fn tiny_scenario() -> ScenarioFile {
    let mut scenario = ScenarioFile::default();
    scenario.tasks.michelson.budget = 6;
    scenario.tasks.cavity.budget = 6;
    scenario.tasks.relay.budget = 6;
    scenario
}

fn plan(out: &Path, tasks: Vec<TaskKind>, seeds: Vec<u64>, sweeps: Vec<SweepSpec>) -> BenchPlan {
    BenchPlan {
        tasks,
        policies: vec!["random".into()],
        seeds,
        scenario: Arc::new(tiny_scenario()),
        scenario_label: "tiny".into(),
        out: out.to_owned(),
        options: MatrixOptions {
            jobs: 2,
            motors: MotorPath::InProcess,
            saved_frames: SavedFrames::None,
            ..MatrixOptions::default()
        },
        sweeps,
    }
}

fn assert_chart(dir: &Path, stem: &str) {
    let png = std::fs::read(dir.join(format!("{stem}.png"))).unwrap();
    let decoded = image::load_from_memory(&png).unwrap();
    assert!(decoded.width() >= 600 && decoded.height() >= 300, "{stem}");
    assert!(png.len() < 200_000, "{stem}.png is {} bytes", png.len());
    let svg = std::fs::read_to_string(dir.join(format!("{stem}.svg"))).unwrap();
    assert!(svg.contains("<svg") && svg.contains("</svg>"), "{stem}.svg");
}

#[test]
fn a_bench_writes_results_summary_charts_and_transcripts() {
    let out = tempfile::tempdir().unwrap();
    let plan = plan(
        out.path(),
        vec![TaskKind::Cavity, TaskKind::Relay],
        vec![0, 1],
        Vec::new(),
    );
    let output = run_bench(&plan, &ProgressBar::hidden()).unwrap();
    assert_eq!(output.records.len(), 4);

    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 5, "{csv}");
    assert!(lines[0].starts_with("knob,value,task,policy,seed,success"));
    assert!(lines[1].starts_with(",,cavity,random,0,"), "{}", lines[1]);
    assert!(lines[4].starts_with(",,relay,random,1,"), "{}", lines[4]);

    let summary = std::fs::read_to_string(out.path().join("summary.md")).unwrap();
    assert!(summary.contains("## cavity (budget 6"), "{summary}");
    assert!(summary.contains("| random | "), "{summary}");
    assert!(summary.contains("Relay milestones"), "{summary}");
    // Each task's row counts that task's successes and carries their 95 % interval.
    for task in [TaskKind::Cavity, TaskKind::Relay] {
        let successes = output
            .records
            .iter()
            .filter(|r| r.summary.task == task && r.summary.success)
            .count();
        let section = summary
            .split("\n## ")
            .find(|s| s.starts_with(&format!("{task} (")))
            .unwrap_or_else(|| panic!("no {task} section: {summary}"));
        let row = format!("| random | {} | ", success_cell(successes, 2));
        assert!(row.contains('–'), "{row}");
        assert!(section.contains(&row), "{row} not in {section}");
        assert!(output.tables.contains(&row), "the printed tables: {row}");
    }
    assert!(
        summary.contains("(charts/speed_accuracy_cavity.png)"),
        "{summary}"
    );

    let charts = out.path().join("charts");
    for stem in [
        "speed_accuracy_cavity",
        "convergence_cavity",
        "speed_accuracy_relay",
        "convergence_relay",
        "relay_milestones",
    ] {
        assert_chart(&charts, stem);
    }
    assert_eq!(output.charts.len(), 10);
    for run in ["cavity-random-seed0", "relay-random-seed1"] {
        let dir = out.path().join("runs").join(run);
        assert!(dir.join("transcript.jsonl").is_file(), "{run}");
        assert!(dir.join("summary.json").is_file(), "{run}");
    }
}

#[test]
fn a_resumed_bench_reads_back_finished_runs_and_runs_the_rest() {
    let out = tempfile::tempdir().unwrap();
    let sweep = SweepSpec::parse("noise=2.5,10").unwrap();
    let first = plan(
        out.path(),
        vec![TaskKind::Cavity],
        vec![0, 1],
        vec![sweep.clone()],
    );
    let earlier = run_bench(&first, &ProgressBar::hidden()).unwrap();
    assert_eq!(earlier.records.len(), 4);
    let runs = out.path().join("runs");
    // One run was cut short (no summary), one summary was damaged.
    std::fs::remove_file(runs.join("noise=10/cavity-random-seed1/summary.json")).unwrap();
    std::fs::write(runs.join("noise=2.5/cavity-random-seed1/summary.json"), "{").unwrap();

    let mut again = first.clone();
    again.options.resume = true;
    again.seeds = vec![0, 1, 2];
    let resumed = run_bench(&again, &ProgressBar::hidden()).unwrap();
    let record = |value: f64, seed: u64| {
        resumed
            .records
            .iter()
            .find(|r| r.setting.unwrap().value == value && r.summary.seed == seed)
            .unwrap()
    };
    for value in [2.5, 10.0] {
        assert!(record(value, 0).elapsed_s.is_none(), "read back");
        assert!(record(value, 1).elapsed_s.is_some(), "run again");
        assert!(record(value, 2).elapsed_s.is_some(), "new");
        let before = earlier
            .records
            .iter()
            .find(|r| r.setting.unwrap().value == value && r.summary.seed == 0)
            .unwrap();
        assert_eq!(record(value, 0).summary, before.summary);
    }
    assert!(
        runs.join("noise=10/cavity-random-seed1/summary.json")
            .is_file()
    );
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert_eq!(csv.lines().count(), 7, "{csv}");

    // Another scenario in the same folder: nothing is read back.
    let mut other = again.clone();
    Arc::make_mut(&mut other.scenario).tasks.cavity.budget = 5;
    let rerun = run_bench(&other, &ProgressBar::hidden()).unwrap();
    assert!(rerun.records.iter().all(|r| r.elapsed_s.is_some()));
    assert!(rerun.records.iter().all(|r| r.summary.budget == 5));
}

#[test]
fn a_sweep_writes_one_group_per_value_and_its_chart() {
    let out = tempfile::tempdir().unwrap();
    let sweep = SweepSpec::parse("artefact_brightness=0,3").unwrap();
    let plan = plan(
        out.path(),
        vec![TaskKind::Michelson, TaskKind::Cavity],
        vec![0],
        vec![sweep],
    );
    let output = run_bench(&plan, &ProgressBar::hidden()).unwrap();
    // The knob only changes the cavity, so only the cavity runs.
    assert_eq!(output.records.len(), 2);
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert!(
        csv.contains("\nartefact_brightness,0,cavity,random,0,"),
        "{csv}"
    );
    assert!(
        csv.contains("\nartefact_brightness,3,cavity,random,0,"),
        "{csv}"
    );
    let summary = std::fs::read_to_string(out.path().join("summary.md")).unwrap();
    assert!(summary.contains("## cavity: success rate"), "{summary}");
    let cell = |value: f64| {
        let successes = output
            .records
            .iter()
            .filter(|r| r.setting.unwrap().value == value && r.summary.success)
            .count();
        success_cell(successes, 1)
    };
    let row = format!("| random | {}, ", cell(0.0));
    assert!(summary.contains(&row), "{row} not in {summary}");
    assert!(
        summary.contains(&format!(" | {}, ", cell(3.0))),
        "{summary}"
    );
    assert!(!summary.contains("## michelson"), "{summary}");
    assert_chart(&out.path().join("charts"), "sweep_artefact_brightness");
    let run = out
        .path()
        .join("runs/artefact_brightness=3/cavity-random-seed0");
    assert!(run.join("transcript.jsonl").is_file());
    // The run folder records the swept scenario, so the run can be repeated alone.
    let recorded = ScenarioFile::load(&run.join("scenario.toml")).unwrap();
    let swept = Knob::ArtefactBrightness
        .apply(&tiny_scenario(), 3.0)
        .unwrap();
    assert_eq!(recorded, swept);
}

#[test]
fn several_sweeps_draw_a_stability_map_per_task() {
    let out = tempfile::tempdir().unwrap();
    let sweeps = vec![
        SweepSpec::parse("flicker=0,0.1").unwrap(),
        SweepSpec::parse("beam_profile=tem01").unwrap(),
        // Changes neither task: skipped among several.
        SweepSpec::parse("placement_error=2").unwrap(),
    ];
    let plan = plan(
        out.path(),
        vec![TaskKind::Michelson, TaskKind::Cavity],
        vec![0],
        sweeps,
    );
    let output = run_bench(&plan, &ProgressBar::hidden()).unwrap();
    assert_eq!(output.records.len(), 6);
    let csv = std::fs::read_to_string(out.path().join("results.csv")).unwrap();
    assert!(
        csv.contains("\nbeam_profile,tem01,cavity,random,0,"),
        "{csv}"
    );
    assert!(csv.contains("\nflicker,0.1,michelson,random,0,"), "{csv}");
    let charts = out.path().join("charts");
    for stem in [
        "sweep_flicker",
        "sweep_beam_profile",
        "stability_michelson",
        "stability_cavity",
    ] {
        assert_chart(&charts, stem);
    }
    assert!(!charts.join("sweep_placement_error.png").exists());
    let summary = std::fs::read_to_string(out.path().join("summary.md")).unwrap();
    assert!(summary.contains("against beam_profile"), "{summary}");
    assert!(summary.contains("| random | "), "{summary}");
}

#[test]
fn sweeps_that_change_nothing_or_break_the_scenario_fail_naming_the_knob() {
    let out = tempfile::tempdir().unwrap();
    let sweep = SweepSpec::parse("placement_error=1,2").unwrap();
    let error = run_bench(
        &plan(out.path(), vec![TaskKind::Cavity], vec![0], vec![sweep]),
        &ProgressBar::hidden(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("placement_error") && error.contains("cavity"),
        "{error}"
    );
    let sweep = SweepSpec::parse("noise=1,400").unwrap();
    let error = run_bench(
        &plan(out.path(), vec![TaskKind::Cavity], vec![0], vec![sweep]),
        &ProgressBar::hidden(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        error.contains("noise=400") && error.contains("noise.std"),
        "{error}"
    );
    assert!(
        !out.path().join("results.csv").exists(),
        "nothing runs before the check"
    );
}

#[test]
fn the_report_shows_every_frame_with_its_action() {
    let out = tempfile::tempdir().unwrap();
    let scenario = Arc::new(tiny_scenario());
    let specs = matrix(
        &[TaskKind::Cavity],
        &["random".to_owned()],
        &[4],
        &scenario,
        None,
        Some(out.path()),
    );
    let options = MatrixOptions {
        jobs: 1,
        motors: MotorPath::Peer,
        saved_frames: SavedFrames::All,
        ..MatrixOptions::default()
    };
    let records = run_matrix(&specs, &options, &ProgressBar::hidden()).unwrap();
    let report = write_report(out.path(), "demo <test>", "intro", &records, &[]).unwrap();
    let html = std::fs::read_to_string(&report).unwrap();
    assert!(html.contains("<title>demo &lt;test&gt;</title>"));
    let run = out.path().join("cavity-random-seed4");
    for evaluation in 0..=6 {
        let thumb = run.join(format!("thumbs/{evaluation:04}.png"));
        let image = image::open(&thumb).unwrap();
        assert_eq!(image.width(), THUMBNAIL_WIDTH);
        assert!(html.contains(&format!("cavity-random-seed4/thumbs/{evaluation:04}.png")));
    }
    assert!(html.contains("0 · start · error "), "{html}");
    assert!(
        html.contains("6 · x="),
        "the last step's action is captioned"
    );
    assert!(html.contains("(done)"), "{html}");
    assert!(run.join("error.svg").is_file() && run.join("error.png").is_file());
}
