//! Replaying a recorded run: the model's answers are read back from the decisions' claims in
//! the transcript and served, in order, by a [`ReplayBackend`] in place of the HTTP client.
//! The VLM policy then parses them exactly as it did live (corrective rounds included), so
//! on the same simulated scene the trajectory and score repeat without calling a model.

use std::collections::VecDeque;

use anyhow::Context;
use async_trait::async_trait;
use serde_json::Value;

use super::VlmOptions;
use super::client::{ChatBackend, ChatRequest, ClientError, Completion};

/// The answers recorded in one decision's claims, in the order they arrived.
pub fn recorded_completions(claims: &Value) -> anyhow::Result<Vec<Completion>> {
    let Some(exchanges) = claims.get("exchanges").and_then(Value::as_array) else {
        return Ok(Vec::new());
    };
    exchanges
        .iter()
        .enumerate()
        .map(|(i, exchange)| {
            serde_json::from_value(exchange["completion"].clone())
                .with_context(|| format!("exchange {i} holds no readable completion"))
        })
        .collect()
}

/// The VLM settings recorded with a run's first decision.
pub fn recorded_options(claims: &Value) -> Option<VlmOptions> {
    serde_json::from_value(claims.pointer("/setup/options")?.clone()).ok()
}

/// Serves recorded answers in order; fails once they run out.
pub struct ReplayBackend {
    completions: VecDeque<Completion>,
}

impl ReplayBackend {
    pub fn new(completions: Vec<Completion>) -> Self {
        Self {
            completions: completions.into(),
        }
    }
}

#[async_trait]
impl ChatBackend for ReplayBackend {
    fn endpoint(&self) -> String {
        "replay".into()
    }

    async fn complete(&mut self, _request: &ChatRequest) -> Result<Completion, ClientError> {
        self.completions
            .pop_front()
            .ok_or_else(|| ClientError::Exhausted("the recording holds no further replies".into()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::vlm::cost::Usage;
    use serde_json::json;

    #[test]
    fn completions_and_options_come_back_from_claims() {
        let completion = Completion {
            text: "{}".into(),
            finish_reason: Some("stop".into()),
            usage: Usage::default(),
            latency_s: 1.5,
            attempts: 2,
            retries: vec!["HTTP 429: slow down".into()],
            model: None,
        };
        let mut options = VlmOptions::new("some/model");
        options.max_consecutive_failures = 3;
        let claims = json!({
            "exchanges": [{"request": {}, "completion": completion, "problem": null}],
            "setup": {"options": options},
        });
        assert_eq!(recorded_completions(&claims).unwrap(), vec![completion]);
        let options = recorded_options(&claims).unwrap();
        assert_eq!(options.model, "some/model");
        assert_eq!(options.max_consecutive_failures, 3);
        assert!(recorded_completions(&json!({})).unwrap().is_empty());
        assert!(recorded_completions(&json!({"exchanges": [{"completion": 1}]})).is_err());
    }
}
