//! Options shared by every command that talks to a controller, and opening the link.

use std::time::Duration;

use anyhow::Context;
use clap::Args;

use crate::link::{AccessKey, Client, ClientError, ClientOptions, Endpoint};
use optalign_protocol::ErrorCode;

/// How long connecting, and each request, may take in all unless told otherwise, ms.
pub const DEFAULT_DEADLINE_MS: u64 = 10_000;

/// Where the controller is and how to authenticate.
#[derive(Debug, Args)]
pub struct ControllerArgs {
    /// Controller URL: tcp://HOST:PORT (Wi-Fi board or simulated peer) or serial://PATH.
    #[arg(long, env = "OPTALIGN_CONTROLLER", value_name = "URL")]
    pub controller: Endpoint,
    /// Access key for motion and configuration over TCP (prefer the environment variable): a
    /// passphrase, or the derived key as `hex:` and 64 hex digits.
    #[arg(long, env = "OPTALIGN_KEY", hide_env_values = true, value_name = "KEY")]
    pub key: Option<String>,
    /// How long to wait for each reply before retransmitting, in milliseconds (1 to
    /// 600,000).
    #[arg(long, default_value_t = 1500, value_name = "MS", value_parser = clap::value_parser!(u64).range(1..=600_000))]
    pub timeout_ms: u64,
    /// How long connecting, and each request, may take in all (retransmissions and
    /// reconnects included), in milliseconds; `stop` keeps trying this long.
    #[arg(long, default_value_t = DEFAULT_DEADLINE_MS, value_name = "MS", value_parser = clap::value_parser!(u64).range(1..=3_600_000))]
    pub deadline_ms: u64,
}

impl ControllerArgs {
    pub async fn connect(&self) -> anyhow::Result<Client> {
        Client::connect(self.controller.clone(), self.options()?)
            .await
            .with_context(|| format!("connecting to {}", self.controller))
    }

    /// How the client behaves, from the flags.
    pub fn options(&self) -> anyhow::Result<ClientOptions> {
        let key = self
            .key
            .as_deref()
            .map(str::parse::<AccessKey>)
            .transpose()
            .context("reading the access key (--key or OPTALIGN_KEY)")?;
        Ok(ClientOptions {
            key,
            request_timeout: Duration::from_millis(self.timeout_ms),
            deadline: Duration::from_millis(self.deadline_ms),
            ..ClientOptions::default()
        })
    }

    /// Adds what the user can do about a refusal (a missing key, say) to a client error.
    pub fn explain(&self, error: ClientError) -> anyhow::Error {
        if let ClientError::OutcomeUnknown { .. } = error {
            return anyhow::Error::new(error)
                .context("see where the axes are with `optalign status` before moving again");
        }
        let hint = match error.code() {
            Some(ErrorCode::UNAUTHORIZED) if self.key.is_none() => Some(
                "this controller needs its access key for motion and configuration over the network: set OPTALIGN_KEY or pass --key",
            ),
            Some(ErrorCode::OUT_OF_LIMITS) => Some(
                "see the axis limits with `optalign status` or change them with `optalign config set AXIS min=.. max=..`",
            ),
            Some(ErrorCode::AXIS_FAULT) => Some(
                "the axis's position is lost: declare where it is with `optalign set-position AXIS=STEPS` (from a reference or a measurement), then move again",
            ),
            Some(ErrorCode::EMERGENCY_STOPPED) => Some(
                "the emergency stop is latched: release it with `optalign clear-emergency`, then move again",
            ),
            _ => None,
        };
        match hint {
            Some(hint) => anyhow::Error::new(error).context(hint),
            None => error.into(),
        }
    }
}
