//! A local OpenAI-compatible chat server for tests and offline demos (`optalign fake-llm`).
//!
//! It listens on 127.0.0.1 only and checks the shape of every request the way a strict
//! provider would: the model id, the message roles and order, every image part decodable as
//! a PNG no larger than the configured side, the output-token limit and reasoning setting,
//! and the API key when one is expected. A request that fails a check gets HTTP 400 naming
//! the problem (and the problem is kept for tests to assert on).
//!
//! Answers come from a script (replies, truncated replies, HTTP errors, a request that
//! never answers), then from an autopilot: a fixed probe pattern per task that ends with
//! done, whose text reports what it measured in the decoded newest image (the brightest
//! region's centroid in the task's coordinates). It is a test fixture, not a policy: it
//! makes no attempt to align anything.

use std::collections::VecDeque;
use std::convert::Infallible;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use http_body_util::{BodyExt, Full};
use hyper::body::{Bytes, Incoming};
use hyper::header::{AUTHORIZATION, CONTENT_TYPE};
use hyper::server::conn::http1;
use hyper::service::service_fn;
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::TokioIo;
use optalign_optics::Frame;
use serde::Deserialize;
use serde_json::{Value, json};
use tokio::net::TcpListener;
use tokio::task::{JoinHandle, JoinSet};

use super::cost::{Pricing, image_tokens};
use super::image::decode_data_url;
use crate::task::TaskKind;

/// One scripted answer.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Scripted {
    /// Answer with this reply text.
    Reply(String),
    /// Answer with this text, marked as cut off by the output-token limit.
    Truncated(String),
    /// Answer with an HTTP error status and message.
    Status { code: u16, message: String },
    /// Never answer.
    Hang,
    /// Answer as the autopilot does.
    Auto,
}

/// What every request must look like.
#[derive(Clone, Debug, Default)]
pub struct Expectations {
    /// The model id, when it must be a particular one.
    pub model: Option<String>,
    /// The bearer key, when one is required.
    pub api_key: Option<String>,
    pub max_tokens: Option<u32>,
    /// The `reasoning_effort` value, when it must be a particular one.
    pub reasoning_effort: Option<String>,
    /// Largest image side accepted, px.
    pub max_image_side: Option<u32>,
}

/// The server's configuration.
#[derive(Clone, Debug)]
pub struct FakeLlmConfig {
    /// The task the autopilot writes replies for.
    pub task: TaskKind,
    /// Michelson and cavity: the autopilot says done on this turn (1-based).
    pub turns: usize,
    /// Answers served before the autopilot takes over.
    pub script: Vec<Scripted>,
    pub expect: Expectations,
    /// Prices listed under `/models` and used for the reported cost.
    pub pricing: Pricing,
}

impl FakeLlmConfig {
    pub fn new(task: TaskKind) -> Self {
        Self {
            task,
            turns: 4,
            script: Vec::new(),
            expect: Expectations::default(),
            pricing: Pricing {
                prompt_usd_per_token: 1e-6,
                completion_usd_per_token: 4e-6,
            },
        }
    }
}

/// One request as the server saw it (image data replaced by `png WxH`).
#[derive(Clone, Debug)]
pub struct SeenRequest {
    pub body: Value,
    pub authorized: bool,
    pub status: u16,
}

struct State {
    script: VecDeque<Scripted>,
    requests: Vec<SeenRequest>,
    problems: Vec<String>,
    last_request: Instant,
}

struct Shared {
    config: FakeLlmConfig,
    state: Mutex<State>,
}

impl Shared {
    fn state(&self) -> std::sync::MutexGuard<'_, State> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }
}

/// A running server; stops when dropped.
pub struct FakeLlm {
    addr: SocketAddr,
    shared: Arc<Shared>,
    task: JoinHandle<()>,
}

impl FakeLlm {
    /// Starts on a free port of 127.0.0.1.
    pub async fn start(config: FakeLlmConfig) -> std::io::Result<Self> {
        Self::bind(config, 0).await
    }

    /// Starts on `port` of 127.0.0.1 (0 = any free port).
    pub async fn bind(config: FakeLlmConfig, port: u16) -> std::io::Result<Self> {
        let listener = TcpListener::bind(SocketAddr::from(([127, 0, 0, 1], port))).await?;
        let addr = listener.local_addr()?;
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                script: config.script.iter().cloned().collect(),
                requests: Vec::new(),
                problems: Vec::new(),
                last_request: Instant::now(),
            }),
            config,
        });
        let serving = shared.clone();
        let task = tokio::spawn(async move {
            let mut connections = JoinSet::new();
            loop {
                let stream = match listener.accept().await {
                    Ok((stream, _)) => stream,
                    Err(_) => {
                        tokio::time::sleep(Duration::from_millis(10)).await;
                        continue;
                    }
                };
                let shared = serving.clone();
                connections.spawn(async move {
                    let service = service_fn(move |request| handle(shared.clone(), request));
                    // A connection error only ends that connection.
                    let _ = http1::Builder::new()
                        .serve_connection(TokioIo::new(stream), service)
                        .await;
                });
                while connections.try_join_next().is_some() {}
            }
        });
        Ok(Self { addr, shared, task })
    }

    /// The base URL to give a client: `http://127.0.0.1:PORT/v1`.
    pub fn base_url(&self) -> String {
        format!("http://{}/v1", self.addr)
    }

    /// Every chat request so far.
    pub fn requests(&self) -> Vec<SeenRequest> {
        self.shared.state().requests.clone()
    }

    /// Every shape violation so far.
    pub fn problems(&self) -> Vec<String> {
        self.shared.state().problems.clone()
    }

    fn idle_for(&self) -> Duration {
        self.shared.state().last_request.elapsed()
    }
}

impl Drop for FakeLlm {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn respond(status: StatusCode, body: &Value) -> Response<Full<Bytes>> {
    let mut response = Response::new(Full::new(Bytes::from(body.to_string())));
    *response.status_mut() = status;
    response.headers_mut().insert(
        CONTENT_TYPE,
        hyper::header::HeaderValue::from_static("application/json"),
    );
    response
}

fn error_body(message: &str) -> Value {
    json!({ "error": { "message": message } })
}

async fn handle(
    shared: Arc<Shared>,
    request: Request<Incoming>,
) -> Result<Response<Full<Bytes>>, Infallible> {
    let (parts, body) = request.into_parts();
    let path = parts.uri.path().to_owned();
    if parts.method == Method::GET && path.ends_with("/models") {
        let pricing = shared.config.pricing;
        let model = shared
            .config
            .expect
            .model
            .clone()
            .unwrap_or_else(|| "fake".into());
        return Ok(respond(
            StatusCode::OK,
            &json!({ "data": [{
                "id": model,
                "pricing": {
                    "prompt": pricing.prompt_usd_per_token.to_string(),
                    "completion": pricing.completion_usd_per_token.to_string(),
                },
            }]}),
        ));
    }
    if parts.method != Method::POST || !path.ends_with("/chat/completions") {
        return Ok(respond(
            StatusCode::NOT_FOUND,
            &error_body(&format!("fake-llm: no route for {} {path}", parts.method)),
        ));
    }
    let bytes = match body.collect().await {
        Ok(collected) => collected.to_bytes(),
        Err(error) => {
            return Ok(respond(
                StatusCode::BAD_REQUEST,
                &error_body(&format!("fake-llm: unreadable body: {error}")),
            ));
        }
    };
    let authorization = parts
        .headers
        .get(AUTHORIZATION)
        .and_then(|v| v.to_str().ok())
        .map(str::to_owned);
    match answer(&shared, authorization.as_deref(), &bytes) {
        Some(response) => Ok(response),
        None => std::future::pending().await,
    }
}

/// The answer to a chat request, or `None` when the script says never to answer.
fn answer(
    shared: &Shared,
    authorization: Option<&str>,
    bytes: &[u8],
) -> Option<Response<Full<Bytes>>> {
    let checked = check_request(&shared.config.expect, authorization, bytes);
    let mut state = shared.state();
    state.last_request = Instant::now();
    let mut seen = SeenRequest {
        body: checked.logged.clone(),
        authorized: authorization.is_some(),
        status: 200,
    };
    if !checked.problems.is_empty() {
        let message = format!("fake-llm: {}", checked.problems.join("; "));
        tracing::warn!("{message}");
        state.problems.extend(checked.problems);
        seen.status = 400;
        state.requests.push(seen);
        return Some(respond(StatusCode::BAD_REQUEST, &error_body(&message)));
    }
    let (text, finish_reason) = match state.script.pop_front().unwrap_or(Scripted::Auto) {
        Scripted::Reply(text) => (text, "stop"),
        Scripted::Truncated(text) => (text, "length"),
        Scripted::Auto => (
            autopilot(
                &shared.config,
                checked.observations.saturating_sub(1),
                checked.newest_image.as_ref(),
            ),
            "stop",
        ),
        Scripted::Status { code, message } => {
            seen.status = code;
            state.requests.push(seen);
            let status = StatusCode::from_u16(code).unwrap_or(StatusCode::INTERNAL_SERVER_ERROR);
            return Some(respond(status, &error_body(&message)));
        }
        Scripted::Hang => {
            seen.status = 0;
            state.requests.push(seen);
            return None;
        }
    };
    let prompt_tokens = checked.prompt_tokens;
    let completion_tokens = (text.len() as u64).div_ceil(4) + 100;
    let pricing = shared.config.pricing;
    let cost = prompt_tokens as f64 * pricing.prompt_usd_per_token
        + completion_tokens as f64 * pricing.completion_usd_per_token;
    state.requests.push(seen);
    Some(respond(
        StatusCode::OK,
        &json!({
            "id": format!("fake-{}", state.requests.len()),
            "object": "chat.completion",
            "model": checked.logged["model"],
            "choices": [{
                "index": 0,
                "message": { "role": "assistant", "content": text },
                "finish_reason": finish_reason,
            }],
            "usage": {
                "prompt_tokens": prompt_tokens,
                "completion_tokens": completion_tokens,
                "total_tokens": prompt_tokens + completion_tokens,
                "completion_tokens_details": { "reasoning_tokens": 100 },
                "cost": cost,
            },
        }),
    ))
}

/// A request after checking.
struct Checked {
    /// The body with image data replaced by `png WxH`.
    logged: Value,
    problems: Vec<String>,
    /// User messages that carry an image (or its omission note): observations so far.
    observations: usize,
    newest_image: Option<Frame>,
    prompt_tokens: u64,
}

fn check_request(expect: &Expectations, authorization: Option<&str>, bytes: &[u8]) -> Checked {
    let mut problems = Vec::new();
    if let Some(key) = &expect.api_key
        && authorization != Some(format!("Bearer {key}").as_str())
    {
        problems.push("the Authorization header does not carry the expected key".into());
    }
    let mut body: Value = match serde_json::from_slice(bytes) {
        Ok(Value::Object(map)) => Value::Object(map),
        Ok(_) | Err(_) => {
            problems.push("the body is not a JSON object".into());
            Value::Null
        }
    };
    match body["model"].as_str() {
        Some(model) if !model.is_empty() => {
            if let Some(expected) = &expect.model
                && model != expected
            {
                problems.push(format!("model {model:?}, expected {expected:?}"));
            }
        }
        _ => problems.push("`model` must be a non-empty string".into()),
    }
    if body.get("stream").is_some_and(|s| s != &Value::Bool(false)) {
        problems.push("streaming is not supported here".into());
    }
    match body["max_tokens"].as_u64() {
        Some(n) if n > 0 => {
            if let Some(expected) = expect.max_tokens
                && n != u64::from(expected)
            {
                problems.push(format!("max_tokens {n}, expected {expected}"));
            }
        }
        _ => problems.push("`max_tokens` must be a positive integer".into()),
    }
    if let Some(expected) = &expect.reasoning_effort
        && body["reasoning_effort"].as_str() != Some(expected.as_str())
    {
        problems.push(format!(
            "reasoning_effort {}, expected {expected:?}",
            body["reasoning_effort"]
        ));
    }
    if let Some(temperature) = body.get("temperature")
        && !temperature
            .as_f64()
            .is_some_and(|t| (0.0..=2.0).contains(&t))
    {
        problems.push(format!("temperature {temperature} is not within 0..=2"));
    }
    let mut observations = 0;
    let mut newest_image = None;
    let mut prompt_tokens = 0u64;
    match body.get_mut("messages").and_then(Value::as_array_mut) {
        Some(messages) if !messages.is_empty() => {
            for (i, message) in messages.iter_mut().enumerate() {
                let role = message["role"].as_str().unwrap_or("").to_owned();
                let expected_roles: &[&str] = if i == 0 {
                    &["system"]
                } else {
                    &["user", "assistant"]
                };
                if !expected_roles.contains(&role.as_str()) {
                    problems.push(format!("messages[{i}] has role {role:?}"));
                }
                match message.get_mut("content") {
                    Some(Value::String(text)) if !text.trim().is_empty() => {
                        prompt_tokens += (text.len() as u64).div_ceil(4);
                    }
                    Some(Value::Array(parts)) if role == "user" => {
                        observations += 1;
                        for (j, part) in parts.iter_mut().enumerate() {
                            check_part(
                                part,
                                i,
                                j,
                                expect,
                                &mut problems,
                                &mut newest_image,
                                &mut prompt_tokens,
                            );
                        }
                    }
                    _ => problems.push(format!("messages[{i}] has no usable content")),
                }
            }
            if messages.last().and_then(|m| m["role"].as_str()) != Some("user") {
                problems.push("the last message must come from the user".into());
            }
            if newest_image.is_none() {
                problems.push("the request carries no image".into());
            }
        }
        _ => problems.push("`messages` must be a non-empty list".into()),
    }
    Checked {
        logged: body,
        problems,
        observations,
        newest_image,
        prompt_tokens,
    }
}

fn check_part(
    part: &mut Value,
    i: usize,
    j: usize,
    expect: &Expectations,
    problems: &mut Vec<String>,
    newest_image: &mut Option<Frame>,
    prompt_tokens: &mut u64,
) {
    match part["type"].as_str() {
        Some("text") => match part["text"].as_str() {
            Some(text) => *prompt_tokens += (text.len() as u64).div_ceil(4),
            None => problems.push(format!("messages[{i}].content[{j}] text part without text")),
        },
        Some("image_url") => {
            let url = part
                .pointer("/image_url/url")
                .and_then(Value::as_str)
                .unwrap_or("");
            match decode_data_url(url) {
                Ok(frame) => {
                    let side = frame.width().max(frame.height());
                    if expect.max_image_side.is_some_and(|max| side > max) {
                        problems.push(format!(
                            "messages[{i}].content[{j}] image side {side} px exceeds {}",
                            expect.max_image_side.unwrap_or_default()
                        ));
                    }
                    *prompt_tokens += image_tokens(frame.width(), frame.height());
                    part["image_url"]["url"] =
                        json!(format!("png {}x{}", frame.width(), frame.height()));
                    *newest_image = Some(frame);
                }
                Err(error) => problems.push(format!("messages[{i}].content[{j}]: {error}")),
            }
        }
        other => problems.push(format!(
            "messages[{i}].content[{j}] has unsupported type {other:?}"
        )),
    }
}

/// The brightest region of a frame: its centroid in normalised coordinates (x right, y up)
/// and in pixels, or `None` when nothing stands out from the background.
fn bright_spot(frame: &Frame) -> Option<([f64; 2], [f64; 2])> {
    let pixels = frame.to_8bit();
    let mut histogram = [0usize; 256];
    for &p in &pixels {
        histogram[usize::from(p)] += 1;
    }
    let mut below = 0;
    let median = histogram.iter().position(|&count| {
        below += count;
        below * 2 > pixels.len()
    })? as f64;
    let max = histogram.iter().rposition(|&count| count > 0)? as f64;
    if max - median < 25.0 {
        return None;
    }
    let threshold = median + 0.5 * (max - median);
    let (mut sx, mut sy, mut n) = (0.0, 0.0, 0.0);
    let width = frame.width() as usize;
    for (i, &p) in pixels.iter().enumerate() {
        if f64::from(p) >= threshold {
            sx += (i % width) as f64;
            sy += (i / width) as f64;
            n += 1.0;
        }
    }
    let (cx, cy) = (sx / n, sy / n);
    let normalised = [
        2.0 * cx / f64::from(frame.width()) - 1.0,
        1.0 - 2.0 * cy / f64::from(frame.height()),
    ];
    Some((normalised, [cx, cy]))
}

fn autopilot(config: &FakeLlmConfig, turn: usize, image: Option<&Frame>) -> String {
    let spot = image.and_then(bright_spot);
    let seen = match spot {
        Some(([x, y], [px, py])) => {
            format!("brightest region centred at x={x:.3}, y={y:.3} (pixel {px:.0}, {py:.0})")
        }
        None => "no region stands out from the background".to_owned(),
    };
    let last = turn + 1 >= config.turns;
    let step = i32::try_from(turn + 1)
        .unwrap_or(i32::MAX)
        .saturating_mul(500);
    match config.task {
        TaskKind::Michelson => json!({
            "visual_description": seen,
            "thought_process": "fixed probe pattern of the test server",
            "command_response": "unknown",
            "verification_state": {
                "phase": if last { "verified" } else { "search" },
                "mirror_1_beam": seen,
                "mirror_2_beam": "unknown",
                "next_test": "the next probe",
            },
            "command": {
                "mirror_1_axis_1": step,
                "mirror_1_axis_2": -step / 2,
                "mirror_2_axis_1": -step,
                "mirror_2_axis_2": step / 2,
            },
            "done": last,
        }),
        TaskKind::Cavity => {
            let command = json!({ "x": -step, "y": step / 2 });
            let observation = match spot {
                Some(([x, y], _)) => json!({
                    "image_index": turn, "command": {"x": -step + 500, "y": (step - 500) / 2},
                    "visibility": "visible", "x": x, "y": y,
                    "confidence": "low", "evidence": seen,
                }),
                None => json!({
                    "image_index": turn, "command": {"x": -step + 500, "y": (step - 500) / 2},
                    "visibility": "unknown", "x": null, "y": null,
                    "confidence": "low", "evidence": seen,
                }),
            };
            json!({
                "visual_description": seen,
                "image_observations": [observation],
                "strategy_summary": "fixed probe pattern of the test server",
                "done": last,
                "probe_commands": if last { json!([]) } else { json!([command]) },
                "final_command": if last { command } else { Value::Null },
            })
        }
        TaskKind::Relay => match turn {
            0 => json!({ "action": "measure", "station": "C1", "reason": format!("at C8: {seen}") }),
            1 => json!({ "action": "tilt", "mirror": "M1", "vertical": 1000, "horizontal": 0, "reason": format!("at C1: {seen}") }),
            2 => json!({ "action": "measure", "station": "C8", "reason": format!("at C1 after the tilt: {seen}") }),
            _ => json!({ "action": "done", "reason": format!("at C8: {seen}") }),
        },
    }
    .to_string()
}

/// `optalign fake-llm`: serve the test server on loopback until it has been idle a while.
#[derive(Debug, clap::Args)]
pub struct FakeLlmArgs {
    /// The task the autopilot answers for.
    #[arg(long)]
    task: TaskKind,
    /// Port on 127.0.0.1; 0 picks a free one.
    #[arg(long, default_value_t = 0)]
    port: u16,
    /// Michelson and cavity: the autopilot says done on this turn.
    #[arg(long, default_value_t = 4)]
    turns: usize,
    /// A JSON list of scripted answers served before the autopilot, e.g.
    /// [{"status": {"code": 429, "message": "slow down"}}, {"reply": "..."}, "auto"].
    #[arg(long, value_name = "FILE")]
    script: Option<PathBuf>,
    /// Refuse requests for any other model id.
    #[arg(long)]
    model: Option<String>,
    /// Refuse images whose longer side exceeds this, px.
    #[arg(long)]
    max_image_side: Option<u32>,
    /// Stop after this many seconds without a request.
    #[arg(long, default_value_t = 60.0)]
    idle_timeout_s: f64,
    /// Stop after this many chat requests.
    #[arg(long)]
    max_requests: Option<usize>,
}

/// Runs `optalign fake-llm`.
pub async fn run_cli(args: FakeLlmArgs) -> anyhow::Result<()> {
    let mut config = FakeLlmConfig::new(args.task);
    config.turns = args.turns.max(1);
    config.expect.model = args.model;
    config.expect.max_image_side = args.max_image_side;
    if let Some(path) = &args.script {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("cannot read script {}", path.display()))?;
        config.script = serde_json::from_str(&text)
            .with_context(|| format!("invalid script {}", path.display()))?;
    }
    let idle = crate::bounds::seconds("--idle-timeout-s", args.idle_timeout_s, false)
        .map_err(anyhow::Error::msg)?;
    let server = FakeLlm::bind(config, args.port)
        .await
        .context("cannot listen on 127.0.0.1")?;
    crate::say!("fake-llm listening on {}", server.base_url());
    let mut reported = 0;
    loop {
        tokio::time::sleep(Duration::from_millis(100)).await;
        let requests = server.requests();
        for (n, request) in requests.iter().enumerate().skip(reported) {
            eprintln!("request {}: HTTP {}", n + 1, request.status);
        }
        reported = requests.len();
        if args.max_requests.is_some_and(|max| requests.len() >= max) {
            eprintln!("fake-llm: served {} requests; stopping", requests.len());
            // Let the last answer reach the client before the server goes away.
            tokio::time::sleep(Duration::from_millis(200)).await;
            return Ok(());
        }
        if server.idle_for() >= idle {
            eprintln!("fake-llm: idle for {:.0} s; stopping", idle.as_secs_f64());
            return Ok(());
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scripts_read_from_json() {
        let script: Vec<Scripted> = serde_json::from_str(
            r#"[{"reply": "hi"}, {"truncated": "{"}, {"status": {"code": 429, "message": "slow"}}, "hang", "auto"]"#,
        )
        .unwrap();
        assert_eq!(
            script,
            vec![
                Scripted::Reply("hi".into()),
                Scripted::Truncated("{".into()),
                Scripted::Status {
                    code: 429,
                    message: "slow".into()
                },
                Scripted::Hang,
                Scripted::Auto,
            ]
        );
    }

    #[test]
    fn the_bright_spot_is_found_in_task_coordinates() {
        let (width, height) = (200u32, 100u32);
        let pixels = (0..width * height)
            .map(|i| {
                let (x, y) = (f64::from(i % width), f64::from(i / width));
                (10.0 + 200.0 * (-((x - 150.0).powi(2) + (y - 25.0).powi(2)) / 50.0).exp()) as u8
            })
            .collect();
        let frame = Frame::new(width, height, pixels).unwrap();
        let ([x, y], [px, py]) = bright_spot(&frame).unwrap();
        assert!((px - 150.0).abs() < 0.5 && (py - 25.0).abs() < 0.5);
        assert!((x - 0.5).abs() < 0.01 && (y - 0.5).abs() < 0.01, "{x} {y}");
        let flat = Frame::new(10, 10, vec![30; 100]).unwrap();
        assert!(bright_spot(&flat).is_none());
    }

    #[test]
    fn autopilot_replies_pass_the_schemas() {
        use crate::policy::vlm::schema::parse_reply;
        for task in TaskKind::ALL {
            let config = FakeLlmConfig::new(task);
            for turn in 0..4 {
                let reply = autopilot(&config, turn, None);
                let parsed = parse_reply(task, &reply).unwrap();
                assert_eq!(parsed.action.is_done(), turn == 3, "{task} turn {turn}");
            }
        }
    }
}
