//! Running a command a user configured for a bench (a camera's capture tool, a robot arm's
//! move script): one placeholder substituted, a time limit, and the command's own error
//! output in the message when it fails.

use std::time::Duration;

use anyhow::{Context, bail};

/// Runs `argv` with `placeholder` replaced by `value` in every argument; `what` names the
/// command in errors ("camera command", "camera mover").
pub async fn run_configured(
    argv: &[String],
    placeholder: &str,
    value: &str,
    timeout: Duration,
    what: &str,
) -> anyhow::Result<()> {
    let args: Vec<String> = argv.iter().map(|a| a.replace(placeholder, value)).collect();
    let program = args.first().context("the command is empty")?;
    let mut command = tokio::process::Command::new(program);
    command
        .args(&args[1..])
        .kill_on_drop(true)
        .stdin(std::process::Stdio::null());
    let output = tokio::time::timeout(timeout, command.output())
        .await
        .with_context(|| format!("{what} {program:?} did not finish within {timeout:?}"))?
        .with_context(|| format!("cannot run {what} {program:?}"))?;
    if !output.status.success() {
        bail!(
            "{what} {program:?} failed ({}): {}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        );
    }
    Ok(())
}
