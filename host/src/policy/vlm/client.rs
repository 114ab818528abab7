//! The chat-completions client: one POST per request to any OpenAI-compatible endpoint
//! (OpenRouter, OpenAI, a local vLLM / llama.cpp / Ollama server) over rustls.
//!
//! Failures are sorted by what helps: 429, 5xx, timeouts, dropped connections and
//! unreadable answers are retried with exponential back-off and jitter, a bounded number of
//! times (honouring `Retry-After`); any other 4xx (400, 401, 403, ...) ends the run with the
//! provider's own message. The API key comes from an environment variable and is never
//! logged or recorded.

use std::net::IpAddr;
use std::time::{Duration, Instant};

use anyhow::Context;
use async_trait::async_trait;
use rand::Rng;
use reqwest::header::{HeaderMap, RETRY_AFTER};
use reqwest::{StatusCode, Url};
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use super::VlmOptions;
use super::cost::{Pricing, Usage};

/// OpenRouter's endpoint, the default.
pub const DEFAULT_BASE_URL: &str = "https://openrouter.ai/api/v1";
/// The variable the API key is read from unless `--api-key-env` names another.
pub const DEFAULT_API_KEY_ENV: &str = "OPENROUTER_API_KEY";

/// One request: the conversation and the inference settings.
#[derive(Clone, Debug)]
pub struct ChatRequest {
    pub model: String,
    pub messages: Vec<Value>,
    pub max_tokens: u32,
    pub temperature: Option<f64>,
    /// The wire value of the reasoning effort; not sent when `None`.
    pub reasoning_effort: Option<&'static str>,
}

/// One answer, as recorded in the transcript (and fed back by a replay).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Completion {
    /// The reply text (empty when the provider sent none).
    pub text: String,
    /// `stop`, `length` (cut off by the token limit), ...
    pub finish_reason: Option<String>,
    pub usage: Usage,
    /// Time from the first attempt to the answer, back-off included, s.
    pub latency_s: f64,
    pub attempts: u32,
    /// Why earlier attempts failed.
    pub retries: Vec<String>,
    /// The model the provider says answered.
    pub model: Option<String>,
}

/// Why no answer came.
#[derive(Debug, thiserror::Error)]
pub enum ClientError {
    /// The provider refused the request; retrying would not help.
    #[error("the provider refused the request (HTTP {status}): {message}")]
    Refused { status: u16, message: String },
    /// Every attempt failed with a retryable error.
    #[error("no usable answer after {attempts} attempts; the last: {last}")]
    GaveUp { attempts: u32, last: String },
    /// A replay ran out of recorded replies.
    #[error("{0}")]
    Exhausted(String),
}

/// Something that answers chat requests: the HTTP client, or a recording during replay.
#[async_trait]
pub trait ChatBackend: Send {
    /// Where requests go, for the records.
    fn endpoint(&self) -> String;

    async fn complete(&mut self, request: &ChatRequest) -> Result<Completion, ClientError>;
}

/// How often and how patiently to retry.
#[derive(Clone, Debug, PartialEq)]
pub struct RetryPolicy {
    /// Attempts per request, the first included.
    pub max_attempts: u32,
    /// Back-off before the first retry; doubles each time.
    pub base_delay: Duration,
    /// Longest wait between attempts (also caps `Retry-After`).
    pub max_delay: Duration,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        Self {
            max_attempts: 6,
            base_delay: Duration::from_secs(1),
            max_delay: Duration::from_secs(60),
        }
    }
}

impl RetryPolicy {
    /// The wait before retry number `retry` (1 = first retry): the doubled base delay,
    /// capped, times a random factor in [0.5, 1] so that many clients do not retry in step;
    /// at least the server's `Retry-After`, never more than the cap.
    pub fn delay(&self, retry: u32, retry_after: Option<Duration>, rng: &mut impl Rng) -> Duration {
        let doubled = self
            .base_delay
            .saturating_mul(1u32 << retry.saturating_sub(1).min(20))
            .min(self.max_delay);
        let jittered = doubled.mul_f64(rng.random_range(0.5..=1.0));
        jittered
            .max(retry_after.unwrap_or_default())
            .min(self.max_delay)
    }
}

/// Whether a URL points at this machine (a local server may run without a key).
pub fn is_loopback(url: &Url) -> bool {
    url.host_str().is_some_and(|host| {
        let host = host.trim_start_matches('[').trim_end_matches(']');
        host.eq_ignore_ascii_case("localhost")
            || host.parse::<IpAddr>().is_ok_and(|ip| ip.is_loopback())
    })
}

/// Parses and checks a base URL.
pub fn parse_base_url(base_url: &str) -> anyhow::Result<Url> {
    let url = Url::parse(base_url.trim_end_matches('/'))
        .with_context(|| format!("--base-url {base_url:?} is not a URL"))?;
    anyhow::ensure!(
        matches!(url.scheme(), "https" | "http"),
        "--base-url {base_url:?}: use an https:// (or, for a local server, http://) URL"
    );
    Ok(url)
}

/// The API key from `variable`; a loopback server may go without one. The error names the
/// variable.
pub fn resolve_api_key(base_url: &Url, variable: &str) -> anyhow::Result<Option<String>> {
    match std::env::var(variable) {
        Ok(key) if !key.trim().is_empty() => Ok(Some(key.trim().to_owned())),
        _ if is_loopback(base_url) => Ok(None),
        _ => anyhow::bail!(
            "no API key: the environment variable {variable} is not set (set it, name another variable with --api-key-env, or point --base-url at a local server)"
        ),
    }
}

/// How the endpoint spells the output-token limit: OpenAI's own API wants
/// `max_completion_tokens` for its reasoning models; OpenRouter and local servers take
/// `max_tokens`.
fn max_tokens_field(url: &Url) -> &'static str {
    if url.host_str() == Some("api.openai.com") {
        "max_completion_tokens"
    } else {
        "max_tokens"
    }
}

/// The provider's message from an error body, or the body itself (shortened).
fn provider_message(body: &str) -> String {
    let parsed: Option<Value> = serde_json::from_str(body).ok();
    let message = parsed.as_ref().and_then(|v| {
        v.pointer("/error/message")
            .or_else(|| v.get("message"))
            .or_else(|| v.get("error"))
            .and_then(Value::as_str)
            .map(str::to_owned)
    });
    let text = message.unwrap_or_else(|| body.trim().to_owned());
    if text.is_empty() {
        "(no message)".into()
    } else if text.chars().count() > 500 {
        format!("{}...", text.chars().take(500).collect::<String>())
    } else {
        text
    }
}

/// The largest chat answer read, in bytes: far above any real answer (a few kB of JSON),
/// low enough that a broken or hostile server cannot fill the memory.
const LARGEST_ANSWER_BYTES: usize = 8 << 20;

/// The largest model list read (OpenRouter's, with prices, is about 1 MB).
const LARGEST_MODEL_LIST_BYTES: usize = 32 << 20;

/// Why a response body was not read.
#[derive(Debug, thiserror::Error)]
enum BodyError {
    #[error("{}", without_url(.0))]
    Http(reqwest::Error),
    #[error("the answer was larger than {0} bytes; it was not read")]
    TooLarge(usize),
}

/// A response's body as text, refused once it grows past `limit` bytes.
async fn read_bounded(mut response: reqwest::Response, limit: usize) -> Result<String, BodyError> {
    if response
        .content_length()
        .is_some_and(|length| length > limit as u64)
    {
        return Err(BodyError::TooLarge(limit));
    }
    let mut body = Vec::new();
    while let Some(chunk) = response.chunk().await.map_err(BodyError::Http)? {
        if body.len() + chunk.len() > limit {
            return Err(BodyError::TooLarge(limit));
        }
        body.extend_from_slice(&chunk);
    }
    Ok(String::from_utf8_lossy(&body).into_owned())
}

fn retry_after(headers: &HeaderMap) -> Option<Duration> {
    headers
        .get(RETRY_AFTER)?
        .to_str()
        .ok()?
        .trim()
        .parse::<f64>()
        .ok()
        .filter(|s| s.is_finite() && *s >= 0.0)
        .map(|s| Duration::from_secs_f64(s.min(crate::bounds::LONGEST_WAIT_S)))
}

/// The reply text of a chat-completions answer (a string or a list of text parts).
fn reply_text(message: &Value) -> String {
    match message.get("content") {
        Some(Value::String(text)) => text.clone(),
        Some(Value::Array(parts)) => parts
            .iter()
            .filter_map(|part| part.get("text").and_then(Value::as_str))
            .collect::<Vec<_>>()
            .join(""),
        _ => String::new(),
    }
}

/// What one attempt produced.
enum Attempt {
    Answer(Value),
    Retry {
        reason: String,
        after: Option<Duration>,
    },
    Refused(ClientError),
}

/// The HTTP client.
pub struct HttpClient {
    http: reqwest::Client,
    base: Url,
    key: Option<String>,
    retry: RetryPolicy,
    timeout: Duration,
}

impl HttpClient {
    /// Builds the client for `options`; fails at once when the key is missing.
    pub fn new(options: &VlmOptions) -> anyhow::Result<Self> {
        let base = parse_base_url(&options.base_url)?;
        let key = resolve_api_key(&base, &options.api_key_env)?;
        if key.is_some() && base.scheme() == "http" && !is_loopback(&base) {
            tracing::warn!(
                "sending the API key over plain http to {}; prefer https",
                base.host_str().unwrap_or("?")
            );
        }
        let timeout = crate::bounds::seconds("--timeout-s", options.timeout_s, false)
            .map_err(anyhow::Error::msg)?;
        let http = reqwest::Client::builder()
            .timeout(timeout)
            .user_agent(concat!("optalign/", env!("CARGO_PKG_VERSION")))
            .build()
            .context("cannot build the HTTP client")?;
        Ok(Self {
            http,
            base,
            key,
            retry: options.retry.clone(),
            timeout,
        })
    }

    fn url(&self, path: &str) -> String {
        format!("{}/{path}", self.base.as_str().trim_end_matches('/'))
    }

    /// The JSON body for `request`.
    pub fn body(&self, request: &ChatRequest) -> Value {
        let mut body = json!({
            "model": request.model,
            "messages": request.messages,
            "stream": false,
        });
        body[max_tokens_field(&self.base)] = json!(request.max_tokens);
        if let Some(temperature) = request.temperature {
            body["temperature"] = json!(temperature);
        }
        if let Some(effort) = request.reasoning_effort {
            body["reasoning_effort"] = json!(effort);
        }
        body
    }

    async fn attempt(&self, body: &Value) -> Attempt {
        let mut post = self.http.post(self.url("chat/completions")).json(body);
        if let Some(key) = &self.key {
            post = post.bearer_auth(key);
        }
        let response = match post.send().await {
            Ok(response) => response,
            Err(error) => {
                let reason = if error.is_timeout() {
                    format!("no answer within {:.0} s", self.timeout.as_secs_f64())
                } else {
                    format!("request failed: {}", without_url(&error))
                };
                return Attempt::Retry {
                    reason,
                    after: None,
                };
            }
        };
        let status = response.status();
        let after = retry_after(response.headers());
        let text = match read_bounded(response, LARGEST_ANSWER_BYTES).await {
            Ok(text) => text,
            Err(BodyError::Http(error)) => {
                return Attempt::Retry {
                    reason: if error.is_timeout() {
                        format!(
                            "the answer did not finish within {:.0} s",
                            self.timeout.as_secs_f64()
                        )
                    } else {
                        format!("reading the answer failed: {}", without_url(&error))
                    },
                    after: None,
                };
            }
            Err(error @ BodyError::TooLarge(_)) => {
                return Attempt::Retry {
                    reason: error.to_string(),
                    after: None,
                };
            }
        };
        if status == StatusCode::TOO_MANY_REQUESTS || status.is_server_error() {
            return Attempt::Retry {
                reason: format!("HTTP {}: {}", status.as_u16(), provider_message(&text)),
                after,
            };
        }
        if !status.is_success() {
            return Attempt::Refused(ClientError::Refused {
                status: status.as_u16(),
                message: provider_message(&text),
            });
        }
        match serde_json::from_str::<Value>(&text) {
            Ok(answer) if answer.pointer("/choices/0/message").is_some() => Attempt::Answer(answer),
            Ok(answer) if answer.get("error").is_some() => Attempt::Retry {
                reason: format!(
                    "the provider reported an error: {}",
                    provider_message(&text)
                ),
                after,
            },
            Ok(_) => Attempt::Retry {
                reason: "the answer held no choices".into(),
                after,
            },
            Err(error) => Attempt::Retry {
                reason: format!("the answer was not JSON: {error}"),
                after,
            },
        }
    }

    /// The model's prices from the endpoint's `models` list (OpenRouter publishes them);
    /// `None` when the list has no prices for the model.
    pub async fn pricing(&self, model: &str) -> anyhow::Result<Option<Pricing>> {
        let mut get = self.http.get(self.url("models"));
        if let Some(key) = &self.key {
            get = get.bearer_auth(key);
        }
        let response = get
            .send()
            .await
            .map_err(|e| anyhow::anyhow!("{}", without_url(&e)))?;
        let status = response.status();
        let text = read_bounded(response, LARGEST_MODEL_LIST_BYTES)
            .await
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        anyhow::ensure!(
            status.is_success(),
            "listing models failed (HTTP {}): {}",
            status.as_u16(),
            provider_message(&text)
        );
        let list: Value = serde_json::from_str(&text).context("the model list is not JSON")?;
        let price = |entry: &Value, key: &str| -> Option<f64> {
            match entry.pointer(&format!("/pricing/{key}"))? {
                Value::String(text) => text.parse().ok(),
                Value::Number(n) => n.as_f64(),
                _ => None,
            }
        };
        Ok(list["data"]
            .as_array()
            .into_iter()
            .flatten()
            .find(|entry| entry["id"] == model)
            .and_then(|entry| {
                Some(Pricing {
                    prompt_usd_per_token: price(entry, "prompt")?,
                    completion_usd_per_token: price(entry, "completion")?,
                })
            }))
    }
}

/// A reqwest error and its causes on one line, without the URL (noise in messages).
fn without_url(error: &reqwest::Error) -> String {
    let mut text = error.to_string();
    if let Some(url) = error.url() {
        text = text.replace(&format!(" for url ({url})"), "");
    }
    let mut cause = std::error::Error::source(error);
    while let Some(inner) = cause {
        let inner_text = inner.to_string();
        if !text.contains(&inner_text) {
            text.push_str(": ");
            text.push_str(&inner_text);
        }
        cause = inner.source();
    }
    text
}

/// The prices of `options.model` from the endpoint's model list (see [`HttpClient::pricing`]).
pub async fn fetch_pricing(options: &VlmOptions) -> anyhow::Result<Option<Pricing>> {
    HttpClient::new(options)?.pricing(&options.model).await
}

#[async_trait]
impl ChatBackend for HttpClient {
    fn endpoint(&self) -> String {
        self.url("chat/completions")
    }

    async fn complete(&mut self, request: &ChatRequest) -> Result<Completion, ClientError> {
        let body = self.body(request);
        let started = Instant::now();
        let mut retries = Vec::new();
        let mut attempts = 0;
        loop {
            attempts += 1;
            match self.attempt(&body).await {
                Attempt::Answer(answer) => {
                    let choice = &answer["choices"][0];
                    return Ok(Completion {
                        text: reply_text(&choice["message"]),
                        finish_reason: choice["finish_reason"].as_str().map(str::to_owned),
                        usage: Usage::from_response(answer.get("usage")),
                        latency_s: started.elapsed().as_secs_f64(),
                        attempts,
                        retries,
                        model: answer["model"].as_str().map(str::to_owned),
                    });
                }
                Attempt::Refused(error) => return Err(error),
                Attempt::Retry { reason, after } => {
                    if attempts >= self.retry.max_attempts {
                        return Err(ClientError::GaveUp {
                            attempts,
                            last: reason,
                        });
                    }
                    let delay = self.retry.delay(attempts, after, &mut rand::rng());
                    tracing::warn!(
                        "model request attempt {attempts} failed ({reason}); retrying in {:.1} s",
                        delay.as_secs_f64()
                    );
                    retries.push(reason);
                    tokio::time::sleep(delay).await;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn back_off_doubles_with_jitter_and_stays_bounded() {
        let policy = RetryPolicy {
            max_attempts: 10,
            base_delay: Duration::from_millis(100),
            max_delay: Duration::from_secs(2),
        };
        let mut rng = rand::rng();
        for _ in 0..50 {
            let first = policy.delay(1, None, &mut rng);
            assert!((50..=100).contains(&first.as_millis()), "{first:?}");
            let third = policy.delay(3, None, &mut rng);
            assert!((200..=400).contains(&third.as_millis()), "{third:?}");
            assert!(policy.delay(30, None, &mut rng) <= Duration::from_secs(2));
        }
        let waited = policy.delay(1, Some(Duration::from_secs(1)), &mut rng);
        assert_eq!(waited, Duration::from_secs(1));
        let capped = policy.delay(1, Some(Duration::from_secs(3600)), &mut rng);
        assert_eq!(capped, Duration::from_secs(2));
    }

    #[test]
    fn keys_are_required_except_on_loopback() {
        let variable = "OPTALIGN_TEST_KEY_THAT_IS_NEVER_SET";
        let remote = parse_base_url(DEFAULT_BASE_URL).unwrap();
        let error = resolve_api_key(&remote, variable).unwrap_err().to_string();
        assert!(error.contains(variable), "{error}");
        for local in [
            "http://127.0.0.1:8080/v1",
            "http://localhost:11434/v1",
            "http://[::1]:8000/v1",
        ] {
            let url = parse_base_url(local).unwrap();
            assert!(is_loopback(&url), "{local}");
            assert_eq!(resolve_api_key(&url, variable).unwrap(), None);
        }
        assert!(!is_loopback(
            &parse_base_url("http://192.168.1.5/v1").unwrap()
        ));
        assert!(parse_base_url("ftp://example.com").is_err());
        assert!(parse_base_url("not a url").is_err());
    }

    #[test]
    fn bodies_follow_the_endpoint_dialect() {
        let request = ChatRequest {
            model: "openai/gpt-5.6-sol".into(),
            messages: vec![json!({"role": "system", "content": "s"})],
            max_tokens: 12_000,
            temperature: None,
            reasoning_effort: Some("high"),
        };
        let client = |base: &str| {
            let options = VlmOptions {
                base_url: base.into(),
                api_key_env: "OPTALIGN_TEST_KEY_THAT_IS_NEVER_SET".into(),
                ..VlmOptions::new("m")
            };
            HttpClient::new(&options).unwrap()
        };
        let local = client("http://127.0.0.1:9/v1").body(&request);
        assert_eq!(local["max_tokens"], 12_000);
        assert_eq!(local["reasoning_effort"], "high");
        assert!(local.get("temperature").is_none());
        assert_eq!(local["stream"], false);
        let openai_host = parse_base_url("https://api.openai.com/v1").unwrap();
        assert_eq!(max_tokens_field(&openai_host), "max_completion_tokens");
        assert_eq!(
            max_tokens_field(&parse_base_url(DEFAULT_BASE_URL).unwrap()),
            "max_tokens"
        );
    }

    #[test]
    fn provider_messages_are_extracted() {
        assert_eq!(
            provider_message(r#"{"error": {"message": "Invalid API key", "code": 401}}"#),
            "Invalid API key"
        );
        assert_eq!(provider_message("Bad Gateway"), "Bad Gateway");
        assert_eq!(provider_message(""), "(no message)");
        assert_eq!(
            reply_text(
                &json!({"content": [{"type": "text", "text": "a"}, {"type": "text", "text": "b"}]})
            ),
            "ab"
        );
        assert_eq!(reply_text(&json!({"content": null})), "");
    }
}
