//! The manual mover: asks a person to place the camera at the named station and press Enter.

use std::io::{BufRead, Write};

use anyhow::bail;
use async_trait::async_trait;
use optalign_optics::Station;

use super::CameraMover;

pub struct ManualMover;

#[async_trait]
impl CameraMover for ManualMover {
    async fn move_to(&mut self, station: Station) -> anyhow::Result<()> {
        let answer = tokio::task::spawn_blocking(move || {
            let mut err = std::io::stderr();
            let _ = write!(
                err,
                "place the camera at station {station}, then press Enter: "
            );
            let _ = err.flush();
            let mut line = String::new();
            std::io::stdin()
                .lock()
                .read_line(&mut line)
                .map(|n| (n, line))
        })
        .await??;
        if answer.0 == 0 {
            bail!("input ended while waiting for the camera to be placed at {station}");
        }
        Ok(())
    }

    fn describe(&self) -> String {
        "manual camera placement".into()
    }
}
