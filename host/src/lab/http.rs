//! The HTTP client a bench's network devices (a snapshot camera, a camera mover) are
//! reached with: one request's whole time bounded by the device's configured timeout.

use std::time::Duration;

use anyhow::Context;

/// A client whose every request ends within `timeout`.
pub fn bounded_client(timeout: Duration) -> anyhow::Result<reqwest::Client> {
    reqwest::Client::builder()
        .timeout(timeout)
        .build()
        .context("cannot build the HTTP client")
}
