//! The `optalign` command with `--policy vlm` against the loopback test server: the
//! acceptance run, the key handling, a killed run, `optalign replay`, and the standalone
//! `optalign fake-llm` server.

use std::path::Path;
use std::process::{Output, Stdio};
use std::time::{Duration, Instant};

use optalign::policy::vlm::default_max_tokens;
use optalign::policy::vlm::fake::{Expectations, FakeLlm, FakeLlmConfig, Scripted};
use optalign::task::TaskKind;
use serde_json::Value;
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;

use crate::BIN;
const KEY_VAR: &str = "OPTALIGN_VLM_CLI_TEST_KEY";
const KEY: &str = "test-key-4f1d";

fn optalign() -> Command {
    let mut command = Command::new(BIN);
    command
        .env_remove("OPENROUTER_API_KEY")
        .env_remove(KEY_VAR)
        .env("RUST_LOG", "error")
        .kill_on_drop(true);
    command
}

fn text(output: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&output.stdout),
        String::from_utf8_lossy(&output.stderr)
    )
}

fn config(task: TaskKind, script: Vec<Scripted>) -> FakeLlmConfig {
    let mut config = FakeLlmConfig::new(task);
    config.turns = 3;
    config.script = script;
    config.expect = Expectations {
        model: Some("x".into()),
        api_key: Some(KEY.into()),
        max_tokens: Some(default_max_tokens(task)),
        reasoning_effort: Some("high".into()),
        max_image_side: Some(1024),
    };
    config
}

async fn run_vlm(task: TaskKind, fake: &FakeLlm, out: &Path) -> Output {
    optalign()
        .args([
            "run",
            task.name(),
            "--sim",
            "--policy",
            "vlm",
            "--model",
            "x",
        ])
        .args(["--base-url", &fake.base_url(), "--api-key-env", KEY_VAR])
        .arg("--out")
        .arg(out)
        .env(KEY_VAR, KEY)
        .output()
        .await
        .unwrap()
}

async fn replay(dir: &Path) -> Output {
    optalign().arg("replay").arg(dir).output().await.unwrap()
}

fn transcript(dir: &Path) -> Vec<Value> {
    std::fs::read_to_string(dir.join("transcript.jsonl"))
        .unwrap()
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect()
}

#[tokio::test]
async fn a_michelson_run_completes_against_the_test_server_and_replays_exactly() {
    let fake = FakeLlm::start(config(TaskKind::Michelson, vec![]))
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let output = run_vlm(TaskKind::Michelson, &fake, &out).await;
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(
        printed.contains("michelson seed 0: not aligned after 3 evaluations"),
        "{printed}"
    );
    assert!(printed.contains("model usage: 3 requests"), "{printed}");
    assert!(fake.problems().is_empty(), "{:?}", fake.problems());
    assert!(fake.requests().iter().all(|r| r.authorized));
    let recorded = std::fs::read_to_string(out.join("transcript.jsonl")).unwrap();
    assert!(
        !recorded.contains(KEY),
        "the key must never reach the transcript"
    );
    assert!(out.join("scenario.toml").exists());

    let output = replay(&out).await;
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(
        printed.contains("trajectory and score reproduced exactly: 3 evaluations"),
        "{printed}"
    );
    assert_eq!(fake.requests().len(), 3, "a replay calls no model");
    let summary = |dir: &Path| -> Value {
        serde_json::from_slice(&std::fs::read(dir.join("summary.json")).unwrap()).unwrap()
    };
    assert_eq!(summary(&out), summary(&out.join("replay")));
}

#[tokio::test]
async fn a_run_with_corrections_and_refusals_replays_exactly() {
    let out_of_range = r#"{"visual_description": "primary only", "image_observations": [
        {"image_index": 0, "command": {"x": 0, "y": 0}, "visibility": "offscreen", "x": null,
         "y": null, "confidence": "low", "evidence": "nothing moves yet"}],
        "strategy_summary": "probe", "done": false, "probe_commands": [{"x": 0, "y": -7000}],
        "final_command": null}"#;
    let script = vec![
        Scripted::Reply("Let me think about the cavity first.".into()),
        Scripted::Status {
            code: 429,
            message: "rate limited".into(),
        },
        Scripted::Reply(out_of_range.into()),
    ];
    let fake = FakeLlm::start(config(TaskKind::Cavity, script))
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let output = run_vlm(TaskKind::Cavity, &fake, &out).await;
    assert!(output.status.success(), "{}", text(&output));
    let lines = transcript(&out);
    let refused: Vec<&Value> = lines
        .iter()
        .filter(|l| !l["rejected"].is_null() && l["type"] == "step")
        .collect();
    assert_eq!(refused.len(), 1);
    assert!(
        refused[0]["rejected"]
            .as_str()
            .unwrap()
            .contains("y=-7000 is outside [-5000, 5000]")
    );

    let output = replay(&out).await;
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("reproduced exactly"), "{printed}");
    assert!(printed.contains("(5 model answers)"), "{printed}");
}

#[tokio::test]
async fn a_run_whose_model_never_answers_usably_exits_non_zero_with_every_reply_on_record() {
    // An overlong reply (cut before it is kept) and four that are not JSON: five unusable
    // replies in a row end the run.
    let mut script = vec![Scripted::Reply("x".repeat(300_000))];
    script.extend((0..4).map(|n| Scripted::Reply(format!("no JSON here, try {n}"))));
    let fake = FakeLlm::start(config(TaskKind::Michelson, script))
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let output = run_vlm(TaskKind::Michelson, &fake, &out).await;
    let printed = text(&output);
    assert_eq!(output.status.code(), Some(1), "{printed}");
    assert!(
        printed.contains("the run did not run to its end"),
        "{printed}"
    );
    assert!(printed.contains("failed 5 times in a row"), "{printed}");
    let lines = transcript(&out);
    let kinds: Vec<&str> = lines.iter().map(|l| l["type"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["run", "start", "failure", "end"]);
    let failure = &lines[2];
    assert_eq!(failure["by"], "policy");
    let exchanges = failure["record"]["exchanges"].as_array().unwrap();
    assert_eq!(exchanges.len(), 5, "every unusable reply is on record");
    let first = &exchanges[0];
    assert!(
        first["problem"]
            .as_str()
            .unwrap()
            .contains("300000 bytes long"),
        "{}",
        first["problem"]
    );
    assert_eq!(first["completion"]["text"].as_str().unwrap().len(), 65536);
    assert!(exchanges[4]["completion"]["text"] == "no JSON here, try 3");
    let summary: Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(summary["ended_by"], "policy");
    assert!(
        summary["failure"]
            .as_str()
            .unwrap()
            .contains("policy failed")
    );
    // The overlong reply went back to the model cut, not whole.
    let whole = "x".repeat(65_537);
    assert!(
        fake.requests()
            .iter()
            .all(|r| !r.body.to_string().contains(&whole))
    );
}

#[tokio::test]
async fn without_a_key_the_run_fails_at_once_naming_the_variable() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let started = Instant::now();
    let output = optalign()
        .args([
            "run",
            "michelson",
            "--sim",
            "--policy",
            "vlm",
            "--model",
            "x",
            "--out",
        ])
        .arg(&out)
        .output()
        .await
        .unwrap();
    assert!(!output.status.success());
    let printed = text(&output);
    assert!(printed.contains("OPENROUTER_API_KEY"), "{printed}");
    assert!(started.elapsed() < Duration::from_secs(5));
    assert!(!out.exists(), "nothing is written before the key is found");
    let output = optalign()
        .args(["run", "relay", "--sim", "--policy", "vlm", "--model", "x"])
        .args(["--api-key-env", "SOME_OTHER_KEY_VARIABLE_NEVER_SET"])
        .output()
        .await
        .unwrap();
    assert!(text(&output).contains("SOME_OTHER_KEY_VARIABLE_NEVER_SET"));
}

#[tokio::test]
async fn a_killed_run_leaves_a_readable_transcript_that_replays() {
    let script = vec![Scripted::Auto, Scripted::Auto, Scripted::Hang];
    let fake = FakeLlm::start(config(TaskKind::Cavity, script))
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let mut child = optalign()
        .args(["run", "cavity", "--sim", "--policy", "vlm", "--model", "x"])
        .args(["--base-url", &fake.base_url(), "--api-key-env", KEY_VAR])
        .arg("--out")
        .arg(&out)
        .env(KEY_VAR, KEY)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let path = out.join("transcript.jsonl");
    let deadline = Instant::now() + Duration::from_secs(60);
    while fake.requests().len() < 3 {
        assert!(
            Instant::now() < deadline,
            "the run never reached its third request"
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    child.kill().await.unwrap();
    let lines = transcript(&out);
    let kinds: Vec<&str> = lines.iter().map(|l| l["type"].as_str().unwrap()).collect();
    assert_eq!(
        kinds,
        ["run", "start", "step", "step"],
        "{}",
        path.display()
    );
    assert!(!out.join("summary.json").exists());

    let output = replay(&out).await;
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("replayed 2 recorded steps"), "{printed}");
    assert!(printed.contains("the run was interrupted"), "{printed}");
}

#[tokio::test]
async fn the_standalone_test_server_serves_a_relay_run_and_stops_by_itself() {
    let mut server = optalign()
        .args([
            "fake-llm",
            "--task",
            "relay",
            "--max-requests",
            "4",
            "--idle-timeout-s",
            "30",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(server.stdout.take().unwrap()).lines();
    let first = lines.next_line().await.unwrap().unwrap();
    let url = first
        .strip_prefix("fake-llm listening on ")
        .unwrap()
        .to_owned();
    assert!(url.starts_with("http://127.0.0.1:"), "{url}");
    let dir = tempfile::tempdir().unwrap();
    let output = optalign()
        .args([
            "run",
            "relay",
            "--sim",
            "--policy",
            "vlm",
            "--model",
            "x",
            "--base-url",
            &url,
        ])
        .arg("--out")
        .arg(dir.path())
        .output()
        .await
        .unwrap();
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("relay seed 0:"), "{printed}");
    assert!(printed.contains("after 4 evaluations"), "{printed}");
    let status = tokio::time::timeout(Duration::from_secs(10), server.wait())
        .await
        .expect("the server stops after its request limit")
        .unwrap();
    assert!(status.success());
}

#[tokio::test]
async fn a_bench_of_vlm_runs_prints_its_cost_and_needs_yes_when_large() {
    let mut config = FakeLlmConfig::new(TaskKind::Relay);
    config.expect.model = Some("x".into());
    let fake = FakeLlm::start(config).await.unwrap();
    let dir = tempfile::tempdir().unwrap();
    let bench = |yes: bool| {
        let mut command = optalign();
        command
            .args([
                "bench",
                "--tasks",
                "relay",
                "--policies",
                "vlm",
                "--seeds",
                "0..2",
            ])
            .args([
                "--jobs",
                "2",
                "--model",
                "x",
                "--base-url",
                &fake.base_url(),
            ])
            .arg("--out")
            .arg(dir.path());
        if yes {
            command.arg("--yes");
        }
        command
    };
    // Two relay runs at the test server's prices: about $6 each if the budget is spent.
    let output = bench(false).output().await.unwrap();
    let printed = text(&output);
    assert!(!output.status.success());
    assert!(printed.contains("200 requests over 2 run(s)"), "{printed}");
    assert!(printed.contains("pass --yes to start anyway"), "{printed}");
    assert!(
        fake.requests().is_empty(),
        "nothing is sent before the go-ahead"
    );

    let output = bench(true).output().await.unwrap();
    let printed = text(&output);
    assert!(output.status.success(), "{printed}");
    assert!(printed.contains("model usage: 8 requests"), "{printed}");
    assert_eq!(fake.requests().len(), 8);
}
