//! The vision-language-model agent: a policy that sends each camera image to a chat model
//! over any OpenAI-compatible API and turns the model's JSON reply into an action.
//!
//! The whole conversation stays in context, as in the paper: the system prompt, every
//! observation (text plus image) and every reply; `keep_images` sends only the newest
//! images to models with a small context.
//!
//! Two kinds of failure never spend an evaluation, and each has exactly one corrective path:
//! - a reply that cannot be used (no JSON, wrong fields or types, a malformed probe list,
//!   cut off by the token limit) is answered inside [`Policy::decide`] with a message that
//!   names every problem, and the model is asked again;
//! - an action that parses but breaks the task's bounds (a value out of range, done away
//!   from C8) is refused by the run loop, which validates every action against the
//!   [`TaskLimits`](crate::task::TaskLimits); the refusal comes back as
//!   [`Feedback::Rejected`] and becomes a corrective message naming the allowed ranges.
//!
//! Both count towards one limit of consecutive failures, after which the run ends with an
//! error. Every exchange (request metadata without the key, reply text, problem, usage,
//! latency) goes into the decision's claims, which the run loop writes to the transcript
//! next to the hidden-truth score; a replay feeds the recorded replies back through the
//! same parser.

pub mod client;
pub mod conversation;
pub mod cost;
pub mod fake;
pub mod image;
pub mod prompt;
pub mod replay;
pub mod schema;

use std::path::PathBuf;

use async_trait::async_trait;
use serde::{Deserialize, Serialize};
use serde_json::{Value, json};

use self::client::{ChatBackend, ChatRequest, Completion, HttpClient, RetryPolicy};
use self::conversation::Conversation;
use self::cost::{Usage, UsageMeter};
use self::schema::parse_reply;
use super::{Decision, Feedback, Observation, Policy, PolicyError, TaskBrief};
use crate::task::michelson::AXIS_NAMES as MICHELSON_AXES;
use crate::task::relay::{RelayState, axis_label};
use crate::task::{Action, TaskKind};

pub use self::client::{DEFAULT_API_KEY_ENV, DEFAULT_BASE_URL, fetch_pricing};
pub use self::cost::{
    CONFIRM_ABOVE_REQUESTS, CONFIRM_ABOVE_USD, CostEstimate, Pricing, estimate_cost,
    needs_confirmation,
};

/// How hard a reasoning model should think (`reasoning_effort` on the wire).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum ReasoningEffort {
    /// Send no reasoning setting (for models without one).
    Off,
    None,
    Minimal,
    Low,
    Medium,
    High,
    Xhigh,
}

impl ReasoningEffort {
    /// The value sent, if any.
    pub fn wire(self) -> Option<&'static str> {
        match self {
            Self::Off => None,
            Self::None => Some("none"),
            Self::Minimal => Some("minimal"),
            Self::Low => Some("low"),
            Self::Medium => Some("medium"),
            Self::High => Some("high"),
            Self::Xhigh => Some("xhigh"),
        }
    }
}

/// The paper's output-token limits: 20,000 for Michelson and cavity, 12,000 for the relay.
pub fn default_max_tokens(task: TaskKind) -> u32 {
    match task {
        TaskKind::Michelson | TaskKind::Cavity => 20_000,
        TaskKind::Relay => 12_000,
    }
}

/// Everything the VLM policy is configured with (never the key itself).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(default)]
pub struct VlmOptions {
    /// Model id at the endpoint, e.g. `openai/gpt-5.6-sol` on OpenRouter.
    pub model: String,
    /// OpenAI-compatible base URL (the part before `/chat/completions`).
    pub base_url: String,
    /// Environment variable holding the API key.
    pub api_key_env: String,
    pub reasoning_effort: ReasoningEffort,
    /// Output-token limit; `None` = the paper's per-task default.
    pub max_tokens: Option<u32>,
    /// Sampling temperature; `None` = the provider's default (reasoning models often
    /// accept no other).
    pub temperature: Option<f64>,
    /// Time allowed for one HTTP request, s.
    pub timeout_s: f64,
    /// Longest image side sent to the model, px (frames are downscaled to fit).
    pub max_image_side: u32,
    /// Send only the newest N images; `None` = every image, as in the paper.
    pub keep_images: Option<usize>,
    /// A prompt template replacing the built-in one.
    pub prompt: Option<PathBuf>,
    /// Unusable replies and refused actions in a row before the run ends.
    pub max_consecutive_failures: usize,
    #[serde(skip)]
    pub retry: RetryPolicy,
    /// Running usage total, shared with whoever built the options.
    #[serde(skip)]
    pub usage: UsageMeter,
}

impl Default for VlmOptions {
    fn default() -> Self {
        Self {
            model: String::new(),
            base_url: DEFAULT_BASE_URL.into(),
            api_key_env: DEFAULT_API_KEY_ENV.into(),
            reasoning_effort: ReasoningEffort::High,
            max_tokens: None,
            temperature: None,
            timeout_s: 300.0,
            max_image_side: image::DEFAULT_MAX_SIDE,
            keep_images: None,
            prompt: None,
            max_consecutive_failures: 5,
            retry: RetryPolicy::default(),
            usage: UsageMeter::default(),
        }
    }
}

impl VlmOptions {
    /// Defaults for `model`.
    pub fn new(model: &str) -> Self {
        Self {
            model: model.into(),
            ..Self::default()
        }
    }

    /// The output-token limit for `task`.
    pub fn max_tokens_for(&self, task: TaskKind) -> u32 {
        self.max_tokens.unwrap_or_else(|| default_max_tokens(task))
    }

    /// Checks the settings; errors name the flag.
    pub fn validate(&self) -> anyhow::Result<()> {
        anyhow::ensure!(!self.model.trim().is_empty(), "--model is empty");
        anyhow::ensure!(
            self.max_image_side >= 64,
            "--max-image-side must be at least 64 px, got {}",
            self.max_image_side
        );
        anyhow::ensure!(
            self.keep_images != Some(0),
            "--keep-images must be at least 1"
        );
        anyhow::ensure!(
            self.max_tokens != Some(0),
            "--max-tokens must be at least 1"
        );
        if let Some(temperature) = self.temperature {
            anyhow::ensure!(
                (0.0..=2.0).contains(&temperature),
                "--temperature must be within 0..=2, got {temperature}"
            );
        }
        anyhow::ensure!(
            self.max_consecutive_failures >= 1,
            "the limit of consecutive failures must be at least 1"
        );
        Ok(())
    }
}

/// Checks settings and the API key without sending anything: what a bench does before it
/// starts a matrix of VLM runs.
pub fn preflight(options: &VlmOptions) -> anyhow::Result<()> {
    options.validate()?;
    HttpClient::new(options).map(drop)
}

/// The VLM agent.
pub struct VlmPolicy {
    brief: TaskBrief,
    options: VlmOptions,
    backend: Box<dyn ChatBackend>,
    conversation: Conversation,
    /// The absolute setting in force (Michelson, cavity), for the observation text.
    setting: Vec<i32>,
    /// Cumulative tilts and camera station (relay), for the observation text and the
    /// allowed ranges in corrective messages.
    relay: RelayState,
    /// Unusable replies and refused actions since the last executed action.
    failures: usize,
    usage: Usage,
    /// Whether the system prompt and settings still have to be recorded.
    setup_recorded: bool,
}

impl VlmPolicy {
    /// The agent over HTTP; fails at once when the key is missing or a setting is invalid.
    pub fn connect(brief: &TaskBrief, options: &VlmOptions) -> anyhow::Result<Self> {
        let backend = HttpClient::new(options)?;
        Self::with_backend(brief, options, Box::new(backend))
    }

    /// The agent over any backend (a recording, in a replay).
    pub fn with_backend(
        brief: &TaskBrief,
        options: &VlmOptions,
        backend: Box<dyn ChatBackend>,
    ) -> anyhow::Result<Self> {
        options.validate()?;
        let system = prompt::system_prompt(brief, options.prompt.as_deref())?;
        Ok(Self {
            brief: brief.clone(),
            options: options.clone(),
            backend,
            conversation: Conversation::new(system, options.keep_images),
            setting: vec![0; brief.task.axes()],
            relay: RelayState::default(),
            failures: 0,
            usage: Usage::default(),
            setup_recorded: false,
        })
    }

    fn request(&self) -> ChatRequest {
        ChatRequest {
            model: self.options.model.clone(),
            messages: self.conversation.messages(),
            max_tokens: self.options.max_tokens_for(self.brief.task),
            temperature: self.options.temperature,
            reasoning_effort: self.options.reasoning_effort.wire(),
        }
    }

    /// What the records say about a request (never the key, never the images).
    fn request_record(&self, request: &ChatRequest) -> Value {
        let (images, omitted) = self.conversation.image_counts();
        json!({
            "endpoint": self.backend.endpoint(),
            "model": request.model,
            "max_tokens": request.max_tokens,
            "temperature": request.temperature,
            "reasoning_effort": request.reasoning_effort,
            "messages": request.messages.len(),
            "images": images,
            "images_omitted": omitted,
            "sent": self.conversation.last_user_text(),
        })
    }

    /// The current settings or relay state, as told to the model.
    fn state_text(&self) -> String {
        match self.brief.task {
            TaskKind::Michelson => format!(
                "Current settings: {}.",
                MICHELSON_AXES
                    .iter()
                    .zip(&self.setting)
                    .map(|(name, value)| format!("{name}={value}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            TaskKind::Cavity => format!(
                "Current setting: x={}, y={}.",
                self.setting[0], self.setting[1]
            ),
            TaskKind::Relay => format!(
                "The camera is at {}. Commanded tilt totals so far: {}.",
                self.relay.station,
                (0..4)
                    .map(|m| format!(
                        "M{} vertical {:+} horizontal {:+}",
                        m + 1,
                        self.relay.cumulative[2 * m],
                        self.relay.cumulative[2 * m + 1]
                    ))
                    .collect::<Vec<_>>()
                    .join("; ")
            ),
        }
    }

    /// How an executed action is described to the model.
    fn action_text(action: &Action) -> String {
        match action {
            Action::Michelson { command, .. } => MICHELSON_AXES
                .iter()
                .zip(command)
                .map(|(name, value)| format!("{name}={value}"))
                .collect::<Vec<_>>()
                .join(", "),
            Action::Cavity { command, .. } => format!("x={}, y={}", command[0], command[1]),
            Action::Relay(relay) => relay.describe(),
        }
    }

    /// The text sent with an image.
    fn observation_text(&self, observation: &Observation) -> String {
        let index = observation.evaluations_used;
        let budget = self.brief.budget;
        let head = match &observation.feedback {
            Feedback::Executed { action } => format!(
                "Image {index}, taken after action {index} of {budget} ({}).",
                Self::action_text(action)
            ),
            _ => "Image 0, the starting state before any action.".to_owned(),
        };
        let remaining = observation.remaining;
        let last = if remaining == 1 {
            match self.brief.task {
                TaskKind::Relay => " This is your last action.".to_owned(),
                _ => " This is your last command: send done=true with the best setting your evidence supports.".to_owned(),
            }
        } else {
            String::new()
        };
        format!(
            "{head} {} {remaining} of {budget} actions remain.{last}",
            self.state_text()
        )
    }

    /// The ranges allowed now, for a corrective message.
    fn allowed_text(&self) -> String {
        let limits = &self.brief.limits;
        match self.brief.task {
            TaskKind::Michelson => format!(
                "Allowed settings: {}",
                MICHELSON_AXES
                    .iter()
                    .zip(limits.michelson.ranges)
                    .map(|(name, range)| format!("{name} {range}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            TaskKind::Cavity => format!(
                "Allowed settings: x {}, y {}",
                limits.cavity.ranges[0], limits.cavity.ranges[1]
            ),
            TaskKind::Relay => format!(
                "Tilts allowed now (each tilt within [-{step}, {step}], totals within [-{total}, {total}]): {}. The camera is at {}; done is accepted only at C8",
                (0..8)
                    .map(|axis| {
                        let (low, high) = self.relay.allowed(&limits.relay, axis);
                        format!("{} [{low}, {high}]", axis_label(axis))
                    })
                    .collect::<Vec<_>>()
                    .join(", "),
                self.relay.station,
                step = limits.relay.max_step,
                total = limits.relay.max_cumulative,
            ),
        }
    }

    /// Counts a failure; ends the run when there were too many in a row.
    fn failed(&mut self, what: &str) -> Result<(), PolicyError> {
        self.failures += 1;
        if self.failures >= self.options.max_consecutive_failures {
            return Err(PolicyError::new(format!(
                "the model failed {} times in a row without a usable action; the last failure: {what}",
                self.failures
            )));
        }
        Ok(())
    }

    /// Why a completion cannot be used, or the parsed reply.
    fn interpret(&self, completion: &Completion) -> Result<schema::Parsed, String> {
        if completion.finish_reason.as_deref() == Some("length") {
            return Err(format!(
                "it was cut off at the output limit of {} tokens before it was complete; reason more briefly and send the whole JSON object",
                self.options.max_tokens_for(self.brief.task)
            ));
        }
        parse_reply(self.brief.task, &completion.text)
    }

    fn note_outcome(&mut self, feedback: &Feedback) -> Result<(), PolicyError> {
        match feedback {
            Feedback::Start => Ok(()),
            Feedback::Executed { action } => {
                self.failures = 0;
                match action {
                    Action::Michelson { command, .. } => self.setting = command.to_vec(),
                    Action::Cavity { command, .. } => self.setting = command.to_vec(),
                    Action::Relay(relay) => self.relay.apply(relay),
                }
                Ok(())
            }
            Feedback::Rejected { reason, .. } => {
                self.failed(&format!("an action was refused: {reason}"))?;
                let text = format!(
                    "Your last action was refused: {reason}. Nothing moved and no action was charged; the image is unchanged. {}. Send a corrected reply.",
                    self.allowed_text()
                );
                self.conversation.push_user(text, None);
                Ok(())
            }
        }
    }
}

/// The longest reply kept, in bytes: a usable reply is a JSON object of a few kB; a longer
/// one is cut here before it is recorded or sent back with the conversation.
const LONGEST_REPLY_BYTES: usize = 64 * 1024;

/// Cuts `text` to [`LONGEST_REPLY_BYTES`] (at a character boundary); returns its original
/// length when it was longer.
fn cut_overlong(text: &mut String) -> Option<usize> {
    let length = text.len();
    if length <= LONGEST_REPLY_BYTES {
        return None;
    }
    let mut end = LONGEST_REPLY_BYTES;
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    text.truncate(end);
    Some(length)
}

#[async_trait]
impl Policy for VlmPolicy {
    fn name(&self) -> String {
        "vlm".into()
    }

    async fn decide(&mut self, observation: &Observation) -> Result<Decision, PolicyError> {
        self.note_outcome(&observation.feedback)?;
        if !matches!(observation.feedback, Feedback::Rejected { .. }) {
            let image = image::prepare(&observation.image, self.options.max_image_side)
                .map_err(|e| PolicyError::new(format!("cannot prepare the image: {e}")))?;
            let text = self.observation_text(observation);
            self.conversation.push_user(text, Some(image));
        }
        let mut exchanges = Vec::new();
        let mut latency_s = 0.0;
        let unused = |exchanges: &Vec<serde_json::Value>, error: PolicyError| {
            error.with_record(json!({ "exchanges": exchanges }))
        };
        loop {
            let request = self.request();
            let record = self.request_record(&request);
            let mut completion = match self.backend.complete(&request).await {
                Ok(completion) => completion,
                Err(e) => {
                    let error = PolicyError::new(format!("model request failed: {e}"));
                    return Err(unused(&exchanges, error));
                }
            };
            let overlong = cut_overlong(&mut completion.text);
            latency_s += completion.latency_s;
            self.usage.add(&completion.usage);
            self.options.usage.add(&completion.usage);
            self.conversation.push_assistant(&completion.text);
            let outcome = match overlong {
                Some(length) => Err(format!(
                    "it was {length} bytes long, over the limit of {LONGEST_REPLY_BYTES}; send one short JSON object"
                )),
                None => self.interpret(&completion),
            };
            exchanges.push(json!({
                "request": record,
                "completion": completion,
                "problem": outcome.as_ref().err(),
            }));
            match outcome {
                Ok(parsed) => {
                    let mut claims = json!({
                        "agent": parsed.claims,
                        "exchanges": exchanges,
                        "usage_run": self.usage,
                    });
                    if !self.setup_recorded {
                        self.setup_recorded = true;
                        claims["setup"] = json!({
                            "system_prompt": self.conversation.system(),
                            "options": self.options,
                        });
                    }
                    return Ok(Decision {
                        action: parsed.action,
                        claims: Some(claims),
                        latency_s,
                    });
                }
                Err(problem) => {
                    self.failed(&format!("an unusable reply: {problem}"))
                        .map_err(|error| unused(&exchanges, error))?;
                    let text = format!(
                        "Your reply could not be used: {problem}. Nothing was executed and no action was charged. Send your reply again as one JSON object in the required format."
                    );
                    self.conversation.push_user(text, None);
                }
            }
        }
    }
}
