//! The live monitor over HTTP on loopback: the token guard refuses every request without
//! the token (the stop included) and the CLI's `run --monitor` stops a run from its stop
//! endpoint with the reason in summary.json.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use optalign::monitor::{Access, Hub, RunMonitor, start};

use crate::BIN;

#[tokio::test]
async fn a_monitor_with_a_token_refuses_every_request_without_it() {
    let run = RunMonitor::new("guarded");
    let access = Access {
        token: Some("0123456789abcdef".into()),
    };
    let server = start(
        "127.0.0.1:0".parse().unwrap(),
        Hub::single(run.clone()),
        access,
    )
    .await
    .unwrap();
    let base = format!("http://{}", server.address);
    assert_eq!(server.url, format!("{base}/?token=0123456789abcdef"));
    let client = reqwest::Client::new();
    for (method, path) in [
        ("GET", "/"),
        ("GET", "/run/0/"),
        ("GET", "/run/0/events"),
        ("GET", "/run/0/frame/0"),
        ("POST", "/run/0/pause?paused=true"),
        ("POST", "/run/0/step"),
        ("POST", "/run/0/stop"),
        ("POST", "/run/0/stop?token=wrong"),
        ("POST", "/run/0/stop?token=0123456789abcdeF"),
    ] {
        let request = match method {
            "GET" => client.get(format!("{base}{path}")),
            _ => client.post(format!("{base}{path}")),
        };
        let response = request.send().await.unwrap();
        assert_eq!(response.status(), 401, "{method} {path}");
        assert!(response.text().await.unwrap().contains("needs the token"));
    }
    assert_eq!(run.control().stop, None, "a refused stop stops nothing");
    assert!(!run.control().paused);

    let page = client
        .get(format!("{base}/run/0/?token=0123456789abcdef"))
        .send()
        .await
        .unwrap();
    assert_eq!(page.status(), 200);
    assert!(page.text().await.unwrap().contains("id=\"stop\""));
    let stop = client
        .post(format!("{base}/run/0/stop?token=0123456789abcdef"))
        .send()
        .await
        .unwrap();
    assert_eq!(stop.status(), 204);
    assert!(run.control().stop.is_some());
}

#[tokio::test]
async fn a_recorded_run_is_served_with_its_saved_frames_and_refuses_commands() {
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("src/monitor/testdata/recorded-michelson");
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(
        fixture.join("transcript.jsonl"),
        dir.path().join("transcript.jsonl"),
    )
    .unwrap();
    std::fs::create_dir(dir.path().join("frames")).unwrap();
    let pixels = (0..64 * 48).map(|i| (i % 251) as u8).collect();
    let frame = optalign_optics::Frame::new(64, 48, pixels).unwrap();
    let png = frame.encode_png().unwrap();
    std::fs::write(dir.path().join("frames/0003.png"), &png).unwrap();

    let recorded = optalign::monitor::load_recorded(dir.path()).unwrap();
    let access = Access::for_address("127.0.0.1:0".parse().unwrap(), false);
    let server = start(
        "127.0.0.1:0".parse().unwrap(),
        Hub::single(recorded),
        access,
    )
    .await
    .unwrap();
    let base = format!("http://{}", server.address);
    let client = reqwest::Client::new();
    let frame = client
        .get(format!("{base}/run/0/frame/3"))
        .send()
        .await
        .unwrap();
    assert_eq!(frame.status(), 200);
    assert_eq!(frame.bytes().await.unwrap().as_ref(), png.as_slice());
    let beams: serde_json::Value = client
        .get(format!("{base}/run/0/beams/3"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(
        (beams["width"].clone(), beams["height"].clone()),
        (64.into(), 48.into())
    );
    let missing = client
        .get(format!("{base}/run/0/frame/4"))
        .send()
        .await
        .unwrap();
    assert_eq!(missing.status(), 404);
    assert!(
        missing
            .text()
            .await
            .unwrap()
            .contains("frame 4 is neither the newest nor saved")
    );
    for command in ["stop", "step", "pause?paused=true"] {
        let refused = client
            .post(format!("{base}/run/0/{command}"))
            .send()
            .await
            .unwrap();
        assert_eq!(refused.status(), 409, "{command}");
        assert!(refused.text().await.unwrap().contains("recorded run"));
    }
    let mut events = client
        .get(format!("{base}/run/0/events"))
        .send()
        .await
        .unwrap();
    let mut text = String::new();
    while !text.contains("\n\n") {
        let chunk = tokio::time::timeout(Duration::from_secs(10), events.chunk())
            .await
            .unwrap()
            .unwrap()
            .expect("the first update");
        text.push_str(&String::from_utf8_lossy(&chunk));
    }
    let data = text
        .lines()
        .find_map(|l| l.strip_prefix("data: "))
        .expect("an update event");
    let update: serde_json::Value = serde_json::from_str(data).unwrap();
    assert_eq!(update["status"]["state"], "replay");
    assert_eq!(update["all_frames"], true);
    assert_eq!(update["steps"].as_array().unwrap().len(), 12);
}

/// Kills the child when the test ends, however it ends.
struct Running(Child);

impl Drop for Running {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Starts `optalign run ... --monitor 127.0.0.1:0 --paused`; returns it and the URL it printed.
fn start_monitored_run(out: &std::path::Path, extra: &[&str]) -> (Running, String) {
    let mut child = Command::new(BIN)
        .args([
            "run",
            "michelson",
            "--sim",
            "--policy",
            "vision",
            "--seed",
            "1",
        ])
        .args(["--motors", "peer", "--monitor", "127.0.0.1:0", "--paused"])
        .args(extra)
        .arg("--out")
        .arg(out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    let mut lines = BufReader::new(stderr).lines();
    let url = loop {
        let line = lines
            .next()
            .expect("the run ended before printing its monitor URL")
            .unwrap();
        if let Some(url) = line.strip_prefix("monitor: ") {
            break url.to_owned();
        }
    };
    std::thread::spawn(move || lines.for_each(drop));
    (Running(child), url)
}

/// Waits (at most 60 s) for the child, whose run the operator stopped, to exit; returns
/// its stdout. A stopped run did not run to its end, so the command exits 1.
fn stopped(mut running: Running) -> String {
    let started = Instant::now();
    loop {
        if let Some(status) = running.0.try_wait().unwrap() {
            assert_eq!(status.code(), Some(1), "a stopped run exits 1: {status}");
            let mut out = String::new();
            std::io::Read::read_to_string(running.0.stdout.as_mut().unwrap(), &mut out).unwrap();
            return out;
        }
        assert!(
            started.elapsed() < Duration::from_secs(60),
            "the run did not end"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[tokio::test]
async fn the_stop_endpoint_ends_a_cli_run_with_the_reason_and_a_latched_peer() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (running, url) = start_monitored_run(&out, &["--monitor-token"]);
    let token = url.split("?token=").nth(1).expect("a token was forced");
    let base = url.split("/?").next().unwrap().to_owned();
    let client = reqwest::Client::new();
    assert_eq!(
        client
            .post(format!("{base}/run/0/stop"))
            .send()
            .await
            .unwrap()
            .status(),
        401
    );
    let step = client
        .post(format!("{base}/run/0/step?token={token}"))
        .send()
        .await
        .unwrap();
    assert_eq!(step.status(), 204);
    let deadline = Instant::now() + Duration::from_secs(60);
    // One action, then held again before the next.
    while std::fs::read_to_string(out.join("transcript.jsonl"))
        .unwrap_or_default()
        .matches("\"type\":\"pause\"")
        .count()
        < 2
    {
        assert!(Instant::now() < deadline, "the single step never ran");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let stop = client
        .post(format!("{base}/run/0/stop?token={token}"))
        .send()
        .await
        .unwrap();
    assert_eq!(stop.status(), 204);
    let printed = tokio::task::spawn_blocking(move || stopped(running))
        .await
        .unwrap();
    assert!(printed.contains("after 1 evaluations"), "{printed}");

    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        summary["failure"],
        "stopped by the operator from the monitor"
    );
    assert_eq!(summary["evaluations_used"], 1);
    let transcript = std::fs::read_to_string(out.join("transcript.jsonl")).unwrap();
    let lines: Vec<serde_json::Value> = transcript
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let kinds: Vec<&str> = lines.iter().map(|l| l["type"].as_str().unwrap()).collect();
    assert_eq!(
        kinds,
        [
            "run", "start", "pause", "resume", "step", "pause", "stop", "end"
        ]
    );
    assert_eq!(lines[3]["single_step"], true);
    let stop_line = &lines[6];
    assert_eq!(stop_line["emergency_stop_error"], serde_json::Value::Null);
    assert_eq!(
        stop_line["controllers"][0]["emergency_stopped"], true,
        "the simulated peer reports the emergency stop: {stop_line}"
    );
}

use crate::devtools;

/// Headless Chromium on a simulated run: the page shows the first frame, the evaluation
/// counter advances as the operator steps the run, and the stop button ends it with the
/// simulated peer latched in its emergency stop. Skips without Chromium unless
/// OPTALIGN_REQUIRE_CHROMIUM is set (CI). Set OPTALIGN_MONITOR_SCREENSHOT=FILE to keep a
/// screenshot of the page.
#[tokio::test]
async fn the_page_in_a_real_browser_shows_the_run_and_its_stop_button_stops_it() {
    let Some(chromium) = devtools::chromium() else {
        assert!(
            std::env::var_os("OPTALIGN_REQUIRE_CHROMIUM").is_none(),
            "OPTALIGN_REQUIRE_CHROMIUM is set but there is no Chromium at /usr/bin/chromium or OPTALIGN_CHROMIUM"
        );
        eprintln!(
            "note: skipping the browser test: no Chromium at /usr/bin/chromium (apt-get install chromium, or set OPTALIGN_CHROMIUM)"
        );
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("run");
    let (running, url) = start_monitored_run(&out, &[]);
    let mut browser = devtools::Browser::open(&chromium, &url).await;
    let patience = Duration::from_secs(60);
    browser
        .wait_for(
            "document.getElementById('frame').dataset.frame === '0'",
            "the first frame",
            patience,
        )
        .await;
    browser
        .wait_for(
            "document.getElementById('status').textContent === 'paused'",
            "the run held before its first action",
            patience,
        )
        .await;
    let counter = "document.getElementById('evaluations').textContent";
    assert_eq!(browser.eval(counter).await, "0");
    // For the documentation's picture, on to where the agent's beliefs show.
    let screenshot = std::env::var_os("OPTALIGN_MONITOR_SCREENSHOT");
    let steps = if screenshot.is_some() { 10 } else { 2 };
    for evaluation in 1..=steps {
        browser.click("step").await;
        browser
            .wait_for(
                &format!("{counter} === '{evaluation}' && document.getElementById('frame').dataset.frame === '{evaluation}' && document.getElementById('status').textContent === 'paused'"),
                &format!("evaluation {evaluation} and its frame"),
                patience,
            )
            .await;
    }
    let action = browser
        .eval("document.getElementById('action').textContent")
        .await;
    assert!(action.as_str().unwrap().starts_with("m1=("), "{action}");
    if let Some(path) = screenshot {
        std::fs::write(path, browser.screenshot().await).unwrap();
    }
    browser.click("stop").await;
    browser
        .wait_for(
            "document.getElementById('controllers').textContent.includes('EMERGENCY STOP latched')",
            "the controller's emergency stop",
            patience,
        )
        .await;
    browser
        .wait_for(
            "document.getElementById('status').textContent.includes('stopped by the operator')",
            "the run's end",
            patience,
        )
        .await;
    let printed = tokio::task::spawn_blocking(move || stopped(running))
        .await
        .unwrap();
    assert!(
        printed.contains(&format!("after {steps} evaluations")),
        "{printed}"
    );
    let summary: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        summary["failure"],
        "stopped by the operator from the monitor"
    );
    let transcript = std::fs::read_to_string(out.join("transcript.jsonl")).unwrap();
    let stop: serde_json::Value = transcript
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .find(|l| l["type"] == "stop")
        .expect("a stop line");
    assert_eq!(stop["controllers"][0]["emergency_stopped"], true);
    for axis in stop["controllers"][0]["axes"].as_array().unwrap() {
        assert_eq!(axis["powered"], false, "the coils are off: {axis}");
    }
}
