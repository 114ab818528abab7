//! The VLM policy end to end over HTTP against the loopback test server: full runs of every
//! task, corrective rounds for unusable replies and refused actions, retries, provider
//! refusals, persistent server errors, a missing key, and the image window. No test leaves
//! 127.0.0.1.

use std::time::Duration;

use optalign::policy::vlm::client::RetryPolicy;
use optalign::policy::vlm::fake::{Expectations, FakeLlm, FakeLlmConfig, Scripted};
use optalign::policy::vlm::{VlmOptions, default_max_tokens, fetch_pricing};
use optalign::policy::{PolicyOptions, TaskBrief, build_policy};
use optalign::rig::{MotorPath, SimRig};
use optalign::run::{RunOptions, RunSummary, run_episode};
use optalign::scenario::ScenarioFile;
use optalign::task::TaskKind;
use serde_json::Value;

const MODEL: &str = "test/model";
const NO_KEY: &str = "OPTALIGN_TEST_KEY_THAT_IS_NEVER_SET";

fn config(task: TaskKind, script: Vec<Scripted>) -> FakeLlmConfig {
    let mut config = FakeLlmConfig::new(task);
    config.turns = 3;
    config.script = script;
    config.expect = Expectations {
        model: Some(MODEL.into()),
        api_key: None,
        max_tokens: Some(default_max_tokens(task)),
        reasoning_effort: Some("high".into()),
        max_image_side: Some(1024),
    };
    config
}

struct Outcome {
    summary: RunSummary,
    lines: Vec<Value>,
    fake: FakeLlm,
    _dir: tempfile::TempDir,
}

impl Outcome {
    fn steps(&self) -> Vec<&Value> {
        self.lines.iter().filter(|l| l["type"] == "step").collect()
    }

    /// The newest user text of the n-th request the server answered or refused.
    fn sent(&self, n: usize) -> String {
        let requests = self.fake.requests();
        let message = requests[n].body["messages"]
            .as_array()
            .and_then(|m| m.last())
            .cloned()
            .unwrap_or_default();
        match &message["content"] {
            Value::String(text) => text.clone(),
            Value::Array(parts) => parts[0]["text"].as_str().unwrap_or_default().to_owned(),
            _ => String::new(),
        }
    }
}

async fn run(
    task: TaskKind,
    config: FakeLlmConfig,
    tweak: impl FnOnce(&mut VlmOptions),
) -> Outcome {
    let fake = FakeLlm::start(config).await.unwrap();
    let mut vlm = VlmOptions {
        base_url: fake.base_url(),
        api_key_env: NO_KEY.into(),
        timeout_s: 10.0,
        retry: RetryPolicy {
            max_attempts: 3,
            base_delay: Duration::from_millis(1),
            max_delay: Duration::from_millis(20),
        },
        ..VlmOptions::new(MODEL)
    };
    tweak(&mut vlm);
    let scenario = ScenarioFile::default();
    let brief = TaskBrief::new(task, &scenario.tasks, scenario.geometry(task));
    let mut built = build_policy(
        "vlm",
        &brief,
        &PolicyOptions {
            seed: 1,
            vlm: Some(vlm),
        },
    )
    .unwrap();
    let mut rig = SimRig::new(task, &scenario, 1, MotorPath::InProcess)
        .await
        .unwrap();
    let dir = tempfile::tempdir().unwrap();
    let options = RunOptions {
        out_dir: Some(dir.path().to_owned()),
        seed: 1,
        ..RunOptions::default()
    };
    let summary = run_episode(
        &mut rig,
        built.policy.as_mut(),
        None,
        &scenario.tasks,
        &options,
    )
    .await
    .unwrap();
    let text = std::fs::read_to_string(dir.path().join("transcript.jsonl")).unwrap();
    let lines = text
        .lines()
        .map(|line| serde_json::from_str(line).unwrap())
        .collect();
    Outcome {
        summary,
        lines,
        fake,
        _dir: dir,
    }
}

fn image_parts(body: &Value) -> Vec<String> {
    body["messages"]
        .as_array()
        .into_iter()
        .flatten()
        .filter_map(|m| m["content"].as_array())
        .flatten()
        .filter_map(|p| p["image_url"]["url"].as_str().map(str::to_owned))
        .collect()
}

#[tokio::test]
async fn every_task_runs_to_done_over_http() {
    for (task, evaluations) in [
        (TaskKind::Michelson, 3),
        (TaskKind::Cavity, 3),
        (TaskKind::Relay, 4),
    ] {
        let outcome = run(task, config(task, vec![]), |_| {}).await;
        let summary = &outcome.summary;
        assert_eq!(summary.failure, None, "{task}");
        assert!(summary.declared_done, "{task}");
        assert_eq!(summary.evaluations_used, evaluations, "{task}");
        assert_eq!(summary.rejected_actions, 0);
        assert!(summary.agent_time_s > 0.0);
        assert!(
            outcome.fake.problems().is_empty(),
            "{:?}",
            outcome.fake.problems()
        );
        let requests = outcome.fake.requests();
        assert_eq!(requests.len(), evaluations);
        for (n, request) in requests.iter().enumerate() {
            // The whole history: every image so far, each downscaled to fit 1024 px.
            assert_eq!(
                image_parts(&request.body).len(),
                n + 1,
                "{task} request {n}"
            );
            assert!(!request.authorized, "no key on loopback without one");
            let system = request.body["messages"][0]["content"].as_str().unwrap();
            assert!(system.contains(&format!("{}", summary.budget)), "{task}");
        }
        if task == TaskKind::Michelson {
            assert_eq!(image_parts(&requests[0].body)[0], "png 1024x576");
        }
        assert_eq!(outcome.lines[0]["policy"], "vlm");
        let steps = outcome.steps();
        assert_eq!(steps.len(), evaluations);
        for step in &steps {
            let exchange = &step["claims"]["exchanges"][0];
            assert_eq!(exchange["request"]["model"], MODEL);
            assert!(
                exchange["request"]["endpoint"]
                    .as_str()
                    .unwrap()
                    .starts_with("http://127.0.0.1:")
            );
            assert!(!exchange["completion"]["text"].as_str().unwrap().is_empty());
            assert_eq!(exchange["problem"], Value::Null);
            assert!(step["claims"]["agent"].is_object());
            assert!(
                step["score"].is_object(),
                "the hidden truth sits next to the claims"
            );
            assert!(step["agent_latency_s"].as_f64().unwrap() > 0.0);
        }
        assert!(steps[0]["claims"]["setup"]["system_prompt"].is_string());
        let usage = &steps.last().unwrap()["claims"]["usage_run"];
        assert_eq!(usage["requests"], evaluations);
        assert!(usage["cost_usd"].as_f64().unwrap() > 0.0);
        assert_eq!(outcome.lines.last().unwrap()["type"], "end");
    }
}

#[tokio::test]
async fn unusable_replies_get_a_corrective_message_and_no_evaluation() {
    let script = vec![
        Scripted::Reply("I will now move mirror 1 a little.".into()),
        Scripted::Reply(r#"{"done": false, "command": {"mirror_1_axis_1": 1,}}"#.into()),
        Scripted::Reply(
            r#"{"visual_description": "a", "thought_process": "b", "command_response": "c",
                "verification_state": {"phase": "search", "mirror_1_beam": "?", "mirror_2_beam": "?", "next_test": "?"},
                "done": false}"#
                .into(),
        ),
        Scripted::Truncated("{\"visual_description\": \"two spots".into()),
    ];
    let outcome = run(
        TaskKind::Michelson,
        config(TaskKind::Michelson, script),
        |_| {},
    )
    .await;
    assert_eq!(outcome.summary.failure, None);
    assert_eq!(outcome.summary.evaluations_used, 3);
    assert_eq!(outcome.summary.rejected_actions, 0);
    let first = outcome.steps()[0];
    assert_eq!(first["evaluation"], 1);
    let problems: Vec<String> = first["claims"]["exchanges"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["problem"].as_str().unwrap_or("").to_owned())
        .collect();
    assert_eq!(problems.len(), 5);
    assert!(problems[0].contains("holds no JSON object"), "{problems:?}");
    assert!(
        problems[1].starts_with("the JSON is malformed"),
        "{problems:?}"
    );
    assert!(problems[2].contains("`command` is missing"), "{problems:?}");
    assert!(
        problems[3].contains("cut off at the output limit of 20000 tokens"),
        "{problems:?}"
    );
    assert_eq!(problems[4], "");
    // Each corrective message names the problem of the reply before it.
    for (n, problem) in problems[..4].iter().enumerate() {
        let sent = outcome.sent(n + 1);
        assert!(sent.starts_with("Your reply could not be used: "), "{sent}");
        assert!(sent.contains(problem.as_str()), "{sent}");
        assert!(sent.contains("no action was charged"));
    }
}

#[tokio::test]
async fn an_out_of_range_command_is_refused_with_the_allowed_ranges() {
    let out_of_range = r#"{"visual_description": "bright primary", "image_observations": [
        {"image_index": 0, "command": {"x": 0, "y": 0}, "visibility": "unknown", "x": null, "y": null,
         "confidence": "low", "evidence": "not seen"}],
        "strategy_summary": "big probe", "done": false, "probe_commands": [{"x": 9000, "y": 0}],
        "final_command": null}"#;
    let script = vec![Scripted::Reply(out_of_range.into())];
    let outcome = run(TaskKind::Cavity, config(TaskKind::Cavity, script), |_| {}).await;
    assert_eq!(outcome.summary.failure, None);
    assert!(outcome.summary.declared_done);
    assert_eq!(outcome.summary.rejected_actions, 1);
    let steps = outcome.steps();
    assert_eq!(steps[0]["evaluation"], 0, "a refused action spends nothing");
    assert!(
        steps[0]["rejected"]
            .as_str()
            .unwrap()
            .contains("x=9000 is outside [-8000, 8000]")
    );
    assert_eq!(steps[0]["score"], Value::Null);
    let sent = outcome.sent(1);
    assert!(sent.starts_with("Your last action was refused: "), "{sent}");
    assert!(sent.contains("x=9000 is outside [-8000, 8000]"), "{sent}");
    assert!(
        sent.contains("Allowed settings: x [-8000, 8000], y [-5000, 5000]"),
        "{sent}"
    );
    assert_eq!(
        image_parts(&outcome.fake.requests()[1].body).len(),
        1,
        "no new image"
    );
    assert_eq!(steps[1]["evaluation"], 1);
}

#[tokio::test]
async fn done_away_from_c8_is_refused_and_the_agent_recovers() {
    let script = vec![
        Scripted::Reply(r#"{"action": "measure", "station": "C1", "reason": "dark at C8"}"#.into()),
        Scripted::Reply(r#"{"action": "done", "reason": "spot at C1"}"#.into()),
    ];
    let outcome = run(TaskKind::Relay, config(TaskKind::Relay, script), |_| {}).await;
    assert_eq!(outcome.summary.failure, None);
    assert!(outcome.summary.declared_done);
    // measure C1, (done refused), then the autopilot: tilt M1, measure C8, done.
    assert_eq!(outcome.summary.evaluations_used, 4);
    let refused = outcome.steps()[1];
    assert!(
        refused["rejected"]
            .as_str()
            .unwrap()
            .contains("done is accepted only while the camera is at C8; it is at C1")
    );
    let sent = outcome.sent(2);
    assert!(
        sent.contains("The camera is at C1; done is accepted only at C8"),
        "{sent}"
    );
    assert!(sent.contains("M1 vertical [-15000, 15000]"), "{sent}");
}

#[tokio::test]
async fn rate_limits_and_server_errors_are_retried() {
    let script = vec![
        Scripted::Status {
            code: 429,
            message: "slow down".into(),
        },
        Scripted::Status {
            code: 503,
            message: "overloaded".into(),
        },
    ];
    let outcome = run(TaskKind::Cavity, config(TaskKind::Cavity, script), |_| {}).await;
    assert_eq!(outcome.summary.failure, None);
    assert_eq!(outcome.summary.evaluations_used, 3);
    let completion = &outcome.steps()[0]["claims"]["exchanges"][0]["completion"];
    assert_eq!(completion["attempts"], 3);
    assert_eq!(completion["retries"][0], "HTTP 429: slow down");
    assert_eq!(completion["retries"][1], "HTTP 503: overloaded");
    assert_eq!(outcome.fake.requests().len(), 5);
}

#[tokio::test]
async fn a_request_that_times_out_is_retried() {
    let script = vec![Scripted::Hang];
    let outcome = run(TaskKind::Cavity, config(TaskKind::Cavity, script), |vlm| {
        vlm.timeout_s = 0.3;
    })
    .await;
    assert_eq!(outcome.summary.failure, None);
    let completion = &outcome.steps()[0]["claims"]["exchanges"][0]["completion"];
    assert!(
        completion["retries"][0]
            .as_str()
            .unwrap()
            .contains("no answer within")
    );
}

#[tokio::test]
async fn persistent_server_errors_end_the_run_with_the_transcript_intact() {
    let error = Scripted::Status {
        code: 500,
        message: "internal error".into(),
    };
    let script = vec![Scripted::Auto, error.clone(), error.clone(), error];
    let outcome = run(TaskKind::Cavity, config(TaskKind::Cavity, script), |_| {}).await;
    let failure = outcome.summary.failure.as_deref().unwrap();
    assert!(
        failure.contains("no usable answer after 3 attempts"),
        "{failure}"
    );
    assert!(failure.contains("HTTP 500: internal error"), "{failure}");
    assert_eq!(outcome.summary.evaluations_used, 1);
    let kinds: Vec<&str> = outcome
        .lines
        .iter()
        .map(|l| l["type"].as_str().unwrap())
        .collect();
    assert_eq!(kinds, ["run", "start", "step", "failure", "end"]);
    assert_eq!(outcome.lines[3]["by"], "policy");
    assert_eq!(
        outcome.summary.ended_by,
        Some(optalign::run::EndedBy::Policy)
    );
    assert_eq!(outcome.fake.requests().len(), 4);
}

#[tokio::test]
async fn a_provider_refusal_ends_the_run_with_its_message() {
    let script = vec![Scripted::Status {
        code: 401,
        message: "Invalid API key".into(),
    }];
    let outcome = run(TaskKind::Relay, config(TaskKind::Relay, script), |_| {}).await;
    let failure = outcome.summary.failure.as_deref().unwrap();
    assert!(
        failure.contains("refused the request (HTTP 401): Invalid API key"),
        "{failure}"
    );
    assert_eq!(outcome.fake.requests().len(), 1, "a 401 is not retried");
}

#[tokio::test]
async fn too_many_unusable_replies_in_a_row_end_the_run() {
    let script = vec![Scripted::Reply("no idea".into()); 3];
    let outcome = run(TaskKind::Relay, config(TaskKind::Relay, script), |vlm| {
        vlm.max_consecutive_failures = 3;
    })
    .await;
    let failure = outcome.summary.failure.as_deref().unwrap();
    assert!(failure.contains("failed 3 times in a row"), "{failure}");
    assert!(failure.contains("holds no JSON object"), "{failure}");
    assert_eq!(outcome.summary.evaluations_used, 0);
    assert_eq!(outcome.lines.last().unwrap()["type"], "end");
}

#[tokio::test]
async fn only_the_newest_images_are_sent_when_asked() {
    let mut config = config(TaskKind::Cavity, vec![]);
    config.turns = 4;
    let outcome = run(TaskKind::Cavity, config, |vlm| vlm.keep_images = Some(2)).await;
    assert_eq!(outcome.summary.failure, None);
    let last = outcome.fake.requests().pop().unwrap();
    assert_eq!(image_parts(&last.body).len(), 2);
    let record = &outcome.steps()[3]["claims"]["exchanges"][0]["request"];
    assert_eq!(record["images"], 2);
    assert_eq!(record["images_omitted"], 2);
}

#[tokio::test]
async fn a_missing_key_fails_at_once_and_names_the_variable() {
    let scenario = ScenarioFile::default();
    let brief = TaskBrief {
        task: TaskKind::Michelson,
        limits: scenario.tasks.clone(),
        budget: 60,
        geometry: scenario.geometry(TaskKind::Michelson),
    };
    let vlm = VlmOptions {
        api_key_env: NO_KEY.into(),
        ..VlmOptions::new(MODEL)
    };
    let error = build_policy(
        "vlm",
        &brief,
        &PolicyOptions {
            seed: 0,
            vlm: Some(vlm),
        },
    )
    .err()
    .unwrap()
    .to_string();
    assert!(error.contains(NO_KEY), "{error}");
    let error = build_policy("vlm", &brief, &PolicyOptions::default())
        .err()
        .unwrap()
        .to_string();
    assert!(error.contains("--model"), "{error}");
}

#[tokio::test]
async fn prices_come_from_the_model_list() {
    let fake = FakeLlm::start(config(TaskKind::Cavity, vec![]))
        .await
        .unwrap();
    let vlm = VlmOptions {
        base_url: fake.base_url(),
        api_key_env: NO_KEY.into(),
        ..VlmOptions::new(MODEL)
    };
    let pricing = fetch_pricing(&vlm).await.unwrap().unwrap();
    assert_eq!(pricing.prompt_usd_per_token, 1e-6);
    assert_eq!(pricing.completion_usd_per_token, 4e-6);
    let other = VlmOptions {
        model: "not/listed".into(),
        ..vlm
    };
    assert_eq!(fetch_pricing(&other).await.unwrap(), None);
}
