//! Tokens and money: what each reply used as the provider reported it, summed per run, and
//! a rough estimate of a run's cost before it starts (for `optalign bench`).

use std::fmt;
use std::sync::{Arc, Mutex};

use serde::{Deserialize, Serialize};
use serde_json::Value;

use super::image::scaled_size;
use super::prompt::system_prompt;
use super::{ReasoningEffort, VlmOptions};
use crate::policy::TaskBrief;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// Token counts (and cost, when the provider reports it) of one reply or of many.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Usage {
    pub requests: u64,
    pub prompt_tokens: u64,
    pub completion_tokens: u64,
    /// Part of `completion_tokens` spent on hidden reasoning.
    pub reasoning_tokens: u64,
    /// Part of `prompt_tokens` served from the provider's prompt cache.
    pub cached_tokens: u64,
    /// US dollars, summed over the replies whose provider reported a cost (OpenRouter does).
    pub cost_usd: Option<f64>,
}

impl Usage {
    /// One reply's usage from a chat-completions `usage` object (absent fields count 0).
    pub fn from_response(usage: Option<&Value>) -> Self {
        let count = |path: &[&str]| {
            usage
                .and_then(|usage| path.iter().try_fold(usage, |value, key| value.get(*key)))
                .and_then(Value::as_u64)
                .unwrap_or(0)
        };
        Self {
            requests: 1,
            prompt_tokens: count(&["prompt_tokens"]),
            completion_tokens: count(&["completion_tokens"]),
            reasoning_tokens: count(&["completion_tokens_details", "reasoning_tokens"]),
            cached_tokens: count(&["prompt_tokens_details", "cached_tokens"]),
            cost_usd: usage.and_then(|u| u.get("cost")).and_then(Value::as_f64),
        }
    }

    pub fn add(&mut self, other: &Usage) {
        self.requests += other.requests;
        self.prompt_tokens += other.prompt_tokens;
        self.completion_tokens += other.completion_tokens;
        self.reasoning_tokens += other.reasoning_tokens;
        self.cached_tokens += other.cached_tokens;
        self.cost_usd = match (self.cost_usd, other.cost_usd) {
            (Some(a), Some(b)) => Some(a + b),
            (a, b) => a.or(b),
        };
    }
}

impl fmt::Display for Usage {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} requests, {} prompt tokens ({} cached), {} completion tokens ({} reasoning)",
            self.requests,
            self.prompt_tokens,
            self.cached_tokens,
            self.completion_tokens,
            self.reasoning_tokens
        )?;
        match self.cost_usd {
            Some(usd) => write!(f, ", cost ${usd:.4} as reported by the provider"),
            None => write!(f, ", no cost reported"),
        }
    }
}

/// A shared running total: the policy adds every reply's usage, the command line reads the
/// total after the run.
#[derive(Clone, Debug, Default)]
pub struct UsageMeter(Arc<Mutex<Usage>>);

impl UsageMeter {
    pub fn add(&self, usage: &Usage) {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).add(usage);
    }

    pub fn total(&self) -> Usage {
        self.0.lock().unwrap_or_else(|e| e.into_inner()).clone()
    }
}

/// A model's prices, US dollars per token.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Pricing {
    pub prompt_usd_per_token: f64,
    pub completion_usd_per_token: f64,
}

/// A rough upper estimate of what runs will use.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CostEstimate {
    pub runs: u64,
    pub requests: u64,
    pub prompt_tokens: u64,
    pub completion_tokens: u64,
    /// US dollars, when prices are known.
    pub usd: Option<f64>,
}

impl CostEstimate {
    /// The estimate for `runs` runs like this one.
    pub fn times(&self, runs: u64) -> Self {
        Self {
            runs: self.runs * runs,
            requests: self.requests * runs,
            prompt_tokens: self.prompt_tokens * runs,
            completion_tokens: self.completion_tokens * runs,
            usd: self.usd.map(|usd| usd * runs as f64),
        }
    }

    /// Adds another estimate (another task, say); the dollars stay known only while every
    /// part has them. Adding to an empty estimate copies the other.
    pub fn add(&mut self, other: &CostEstimate) {
        self.usd = match (self.usd, other.usd) {
            _ if self.runs == 0 => other.usd,
            (Some(a), Some(b)) => Some(a + b),
            _ => None,
        };
        self.runs += other.runs;
        self.requests += other.requests;
        self.prompt_tokens += other.prompt_tokens;
        self.completion_tokens += other.completion_tokens;
    }
}

impl fmt::Display for CostEstimate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "at most about {} requests over {} run(s), {:.1} M prompt tokens, {:.2} M completion tokens",
            self.requests,
            self.runs,
            self.prompt_tokens as f64 / 1e6,
            self.completion_tokens as f64 / 1e6
        )?;
        match self.usd {
            Some(usd) => write!(f, ", about ${usd:.2}"),
            None => write!(f, " (price unknown)"),
        }
    }
}

/// Above this estimated spend `optalign bench` asks for confirmation, USD.
pub const CONFIRM_ABOVE_USD: f64 = 10.0;
/// Without prices, above this many requests `optalign bench` asks for confirmation.
pub const CONFIRM_ABOVE_REQUESTS: u64 = 1000;

/// Whether an estimate is large enough to need the user's explicit go-ahead.
pub fn needs_confirmation(estimate: &CostEstimate) -> bool {
    match estimate.usd {
        Some(usd) => usd > CONFIRM_ABOVE_USD,
        None => estimate.requests > CONFIRM_ABOVE_REQUESTS,
    }
}

/// Rough prompt tokens of one image: about one token per 750 pixels (close to what the
/// major providers charge for a 1024 px image), at least 85.
pub fn image_tokens(width: u32, height: u32) -> u64 {
    (u64::from(width) * u64::from(height)).div_ceil(750).max(85)
}

/// Our guess of the reasoning tokens per reply at each effort (providers do not say).
fn reasoning_guess(effort: ReasoningEffort) -> u64 {
    match effort {
        ReasoningEffort::Off | ReasoningEffort::None => 0,
        ReasoningEffort::Minimal => 300,
        ReasoningEffort::Low => 1000,
        ReasoningEffort::Medium => 3000,
        ReasoningEffort::High => 6000,
        ReasoningEffort::Xhigh => 10_000,
    }
}

/// Tokens of the text of one observation message.
const OBSERVATION_TOKENS: u64 = 120;

/// Visible reply tokens (the JSON answer that stays in the history).
fn reply_tokens(task: TaskKind) -> u64 {
    match task {
        TaskKind::Michelson | TaskKind::Cavity => 450,
        TaskKind::Relay => 150,
    }
}

/// Estimates one run of `task` that spends its whole budget with one request per
/// evaluation and the full history in context (or the last `keep_images` images). Retries
/// and corrective rounds are not counted; cache discounts are ignored. `pricing` turns
/// tokens into dollars.
pub fn estimate_cost(
    task: TaskKind,
    scenario: &ScenarioFile,
    options: &VlmOptions,
    pricing: Option<&Pricing>,
) -> anyhow::Result<CostEstimate> {
    let brief = TaskBrief::new(task, &scenario.tasks, scenario.geometry(task));
    let system = system_prompt(&brief, options.prompt.as_deref())?;
    let system_tokens = system.len().div_ceil(4) as u64;
    let (width, height) = match task {
        TaskKind::Michelson => (scenario.michelson.width_px, scenario.michelson.height_px),
        TaskKind::Cavity => (scenario.cavity.width_px, scenario.cavity.height_px),
        TaskKind::Relay => (
            scenario.relay.camera.width_px,
            scenario.relay.camera.height_px,
        ),
    };
    let (width, height) = scaled_size(width, height, options.max_image_side);
    let per_image = image_tokens(width, height);
    let reply = reply_tokens(task);
    let turns = scenario.tasks.budget(task) as u64;
    let keep = options.keep_images.map_or(turns, |keep| keep as u64);
    let prompt_tokens: u64 = (1..=turns)
        .map(|k| system_tokens + k * OBSERVATION_TOKENS + k.min(keep) * per_image + (k - 1) * reply)
        .sum();
    let per_reply = (reasoning_guess(options.reasoning_effort) + reply)
        .min(u64::from(options.max_tokens_for(task)));
    let completion_tokens = turns * per_reply;
    Ok(CostEstimate {
        runs: 1,
        requests: turns,
        prompt_tokens,
        completion_tokens,
        usd: pricing.map(|p| {
            prompt_tokens as f64 * p.prompt_usd_per_token
                + completion_tokens as f64 * p.completion_usd_per_token
        }),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn usage_reads_provider_fields_and_sums() {
        let reply = json!({
            "prompt_tokens": 1000, "completion_tokens": 300, "cost": 0.01,
            "completion_tokens_details": {"reasoning_tokens": 200},
            "prompt_tokens_details": {"cached_tokens": 600}
        });
        let mut total = Usage::from_response(Some(&reply));
        assert_eq!(total.reasoning_tokens, 200);
        assert_eq!(total.cached_tokens, 600);
        total.add(&Usage::from_response(None));
        total.add(&Usage::from_response(Some(&reply)));
        assert_eq!(total.requests, 3);
        assert_eq!(total.prompt_tokens, 2000);
        assert!((total.cost_usd.unwrap() - 0.02).abs() < 1e-12);
        assert!(total.to_string().contains("cost $0.0200"));
        assert_eq!(Usage::from_response(None).cost_usd, None);
    }

    #[test]
    fn estimates_grow_with_history_and_shrink_with_an_image_window() {
        let scenario = ScenarioFile::default();
        let options = VlmOptions::new("m");
        let pricing = Pricing {
            prompt_usd_per_token: 1e-6,
            completion_usd_per_token: 1e-5,
        };
        let full = estimate_cost(TaskKind::Michelson, &scenario, &options, Some(&pricing)).unwrap();
        assert_eq!(full.requests, 60);
        // 60 requests, the last carrying 60 images of 1024 x 576 (787 tokens each).
        assert!(full.prompt_tokens > 60 * 61 / 2 * 787, "{full:?}");
        assert_eq!(full.completion_tokens, 60 * (6000 + 450));
        let usd = full.usd.unwrap();
        assert!(
            (usd - (full.prompt_tokens as f64 * 1e-6 + full.completion_tokens as f64 * 1e-5)).abs()
                < 1e-9
        );
        let windowed = VlmOptions {
            keep_images: Some(4),
            ..options.clone()
        };
        let small = estimate_cost(TaskKind::Michelson, &scenario, &windowed, None).unwrap();
        // Each request k leaves out k - min(k, 4) images.
        let left_out: u64 = (1..=60u64).map(|k| k - k.min(4)).sum();
        assert_eq!(full.prompt_tokens - small.prompt_tokens, left_out * 787);
        assert_eq!(small.usd, None);
        let matrix = full.times(10);
        assert_eq!(matrix.runs, 10);
        let mut sum = CostEstimate::default();
        sum.add(&full);
        sum.add(&full);
        assert_eq!(sum.usd, Some(2.0 * usd));
        assert_eq!(sum.requests, 120);
        sum.add(&small);
        assert_eq!(
            sum.usd, None,
            "a part without prices makes the total unknown"
        );
        assert!(needs_confirmation(&matrix));
        assert!(!needs_confirmation(&small));
        assert!(matrix.to_string().contains("600 requests over 10 run(s)"));
    }
}
