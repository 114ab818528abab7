//! The command mover: runs a configured command per move, for any robot arm with a CLI or
//! a script. `{station}` in the arguments becomes C1..C8; success means the camera is there.

use std::time::Duration;

use async_trait::async_trait;
use optalign_optics::Station;

use super::CameraMover;
use crate::lab::command::run_configured;

pub struct CommandMover {
    argv: Vec<String>,
    timeout: Duration,
}

impl CommandMover {
    pub fn new(argv: Vec<String>, timeout: Duration) -> Self {
        Self { argv, timeout }
    }
}

#[async_trait]
impl CameraMover for CommandMover {
    async fn move_to(&mut self, station: Station) -> anyhow::Result<()> {
        let what = format!("camera mover (to {station})");
        run_configured(
            &self.argv,
            "{station}",
            &station.to_string(),
            self.timeout,
            &what,
        )
        .await
    }

    fn describe(&self) -> String {
        format!(
            "command mover {:?}",
            self.argv.first().map(String::as_str).unwrap_or("")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn substitutes_the_station_and_reports_failures() {
        let dir = tempfile::tempdir().unwrap();
        let log = dir.path().join("log");
        let script = format!("echo $1 >> {}", log.display());
        let mut mover = CommandMover::new(
            vec![
                "sh".into(),
                "-c".into(),
                script,
                "arm".into(),
                "{station}".into(),
            ],
            Duration::from_secs(5),
        );
        mover.move_to(Station::C3).await.unwrap();
        mover.move_to(Station::C8).await.unwrap();
        assert_eq!(std::fs::read_to_string(&log).unwrap(), "C3\nC8\n");
        let mut failing = CommandMover::new(
            vec![
                "sh".into(),
                "-c".into(),
                "echo jammed >&2; exit 3".into(),
                "{station}".into(),
            ],
            Duration::from_secs(5),
        );
        let error = failing.move_to(Station::C1).await.unwrap_err().to_string();
        assert!(
            error.contains("(to C1)") && error.contains("failed") && error.contains("jammed"),
            "{error}"
        );
    }
}
