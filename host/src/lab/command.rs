//! Running a command a user configured for a bench (a camera's capture tool, a robot arm's
//! move script): one placeholder substituted, a time limit, and the command's own error
//! output in the message when it fails. The command runs in a process group of its own, and
//! the whole group is killed when it overruns its time or the run stops waiting for it, so
//! no child of a capture script outlives it.

use std::process::Stdio;
use std::time::Duration;

use anyhow::{Context, bail};
use tokio::io::{AsyncRead, AsyncReadExt};

/// How much of a command's error output is kept for the message; the rest is read and
/// dropped so that a chatty command never blocks on a full pipe.
const KEPT_STDERR_BYTES: u64 = 4096;

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
        .process_group(0)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped());
    let mut child = command
        .spawn()
        .with_context(|| format!("cannot run {what} {program:?}"))?;
    let group = GroupGuard(child.id());
    let stderr = child.stderr.take();
    let finished = async {
        let (status, stderr) = tokio::join!(child.wait(), read_bounded(stderr));
        (status, stderr)
    };
    let (status, stderr) = tokio::time::timeout(timeout, finished)
        .await
        .with_context(|| format!("{what} {program:?} did not finish within {timeout:?}"))?;
    let status = status.with_context(|| format!("cannot wait for {what} {program:?}"))?;
    group.disarm();
    if !status.success() {
        bail!(
            "{what} {program:?} failed ({status}): {}",
            String::from_utf8_lossy(&stderr).trim()
        );
    }
    Ok(())
}

/// The first [`KEPT_STDERR_BYTES`] of a stream, read to its end.
async fn read_bounded(stream: Option<impl AsyncRead + Unpin>) -> Vec<u8> {
    let mut kept = Vec::new();
    if let Some(mut stream) = stream {
        let _ = (&mut stream)
            .take(KEPT_STDERR_BYTES)
            .read_to_end(&mut kept)
            .await;
        let _ = tokio::io::copy(&mut stream, &mut tokio::io::sink()).await;
    }
    kept
}

/// Kills a command's whole process group when dropped before [`GroupGuard::disarm`]: on a
/// timeout, or when the caller stops waiting.
struct GroupGuard(Option<u32>);

impl GroupGuard {
    fn disarm(mut self) {
        self.0 = None;
    }
}

impl Drop for GroupGuard {
    fn drop(&mut self) {
        if let Some(pid) = self.0.and_then(|pid| libc::pid_t::try_from(pid).ok()) {
            // SAFETY: killpg only sends a signal; the group is the one the command leads
            // (process_group(0) made its pid the group id), and a group that is already
            // gone makes it fail with ESRCH, which changes nothing.
            unsafe {
                libc::killpg(pid, libc::SIGKILL);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Whether `pid` runs (a zombie waiting for its new parent to reap it does not).
    fn alive(pid: i32) -> bool {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .ok()
            .and_then(|stat| {
                let state = stat.rsplit_once(')')?.1.trim_start().chars().next()?;
                Some(state != 'Z' && state != 'X')
            })
            .unwrap_or(false)
    }

    #[tokio::test]
    async fn a_timed_out_command_leaves_no_child_behind() {
        let dir = tempfile::tempdir().unwrap();
        let pid_file = dir.path().join("sleeper.pid");
        let script = "sleep 300 & echo $! > {output}; wait";
        let argv = vec!["sh".into(), "-c".into(), script.into()];
        let started = std::time::Instant::now();
        let error = run_configured(
            &argv,
            "{output}",
            &pid_file.to_string_lossy(),
            Duration::from_millis(300),
            "camera command",
        )
        .await
        .unwrap_err();
        assert!(
            error.to_string().contains("did not finish within"),
            "{error}"
        );
        assert!(started.elapsed() < Duration::from_secs(10));
        let sleeper: i32 = std::fs::read_to_string(&pid_file)
            .unwrap()
            .trim()
            .parse()
            .unwrap();
        let deadline = std::time::Instant::now() + Duration::from_secs(5);
        while alive(sleeper) && std::time::Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        assert!(
            !alive(sleeper),
            "the script's sleep {sleeper} survived the timeout"
        );
    }

    #[tokio::test]
    async fn a_failure_quotes_a_bounded_share_of_the_error_output() {
        let argv = vec![
            "sh".into(),
            "-c".into(),
            "head -c 1000000 /dev/zero | tr '\\0' x >&2; echo done; exit 3".into(),
        ];
        let error = run_configured(&argv, "{x}", "", Duration::from_secs(10), "camera mover")
            .await
            .unwrap_err()
            .to_string();
        assert!(error.starts_with("camera mover \"sh\" failed"), "{error}");
        assert!(
            error.len() < KEPT_STDERR_BYTES as usize + 200,
            "{}",
            error.len()
        );
    }
}
