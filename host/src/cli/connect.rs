//! Options shared by every command that talks to a controller, and opening the link.

use std::time::Duration;

use anyhow::Context;
use clap::Args;
use optalign_protocol::auth;

use crate::link::{Client, ClientOptions, Endpoint};

/// Where the controller is and how to authenticate.
#[derive(Debug, Args)]
pub struct ControllerArgs {
    /// Controller URL: tcp://HOST:PORT (Wi-Fi board or simulated peer) or serial://PATH.
    #[arg(long, env = "OPTALIGN_CONTROLLER", value_name = "URL")]
    pub controller: Endpoint,
    /// Access key for motion and configuration over TCP (prefer the environment variable).
    #[arg(long, env = "OPTALIGN_KEY", hide_env_values = true, value_name = "KEY")]
    pub key: Option<String>,
    /// How long to wait for each reply before retransmitting, in milliseconds.
    #[arg(long, default_value_t = 1500, value_name = "MS")]
    pub timeout_ms: u64,
}

impl ControllerArgs {
    pub async fn connect(&self) -> anyhow::Result<Client> {
        let options = ClientOptions {
            key: self.key.as_deref().map(auth::derive_key),
            request_timeout: Duration::from_millis(self.timeout_ms.max(1)),
            ..ClientOptions::default()
        };
        Client::connect(self.controller.clone(), options)
            .await
            .with_context(|| format!("connecting to {}", self.controller))
    }
}
