//! The command camera: runs a user command that writes one image, for any camera that comes
//! with its own capture software.

use std::time::Duration;

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::Frame;

use super::{Camera, decode_image, report_saturation};
use crate::lab::command::run_configured;

/// Runs `argv` (with `{output}` replaced by a fresh path) and reads the image it wrote.
pub struct CommandCamera {
    argv: Vec<String>,
    timeout: Duration,
    dir: tempfile::TempDir,
    captures: u64,
}

impl CommandCamera {
    pub fn new(argv: Vec<String>, timeout: Duration) -> anyhow::Result<Self> {
        Ok(Self {
            argv,
            timeout,
            dir: tempfile::tempdir().context("cannot create a folder for captures")?,
            captures: 0,
        })
    }
}

#[async_trait]
impl Camera for CommandCamera {
    async fn capture(&mut self) -> anyhow::Result<Frame> {
        self.captures += 1;
        let output = self
            .dir
            .path()
            .join(format!("capture-{}.png", self.captures));
        run_configured(
            &self.argv,
            "{output}",
            &output.to_string_lossy(),
            self.timeout,
            "camera command",
        )
        .await?;
        if !output.exists() {
            bail!(
                "camera command {:?} succeeded but wrote no image to {}",
                self.argv[0],
                output.display()
            );
        }
        let frame = decode_image(&output)?;
        let _ = std::fs::remove_file(&output);
        report_saturation(&self.describe(), &frame);
        Ok(frame)
    }

    fn describe(&self) -> String {
        format!(
            "command camera {:?}",
            self.argv.first().map(String::as_str).unwrap_or("")
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn reads_what_the_command_wrote_and_explains_failures() {
        let dir = tempfile::tempdir().unwrap();
        let source = dir.path().join("beam.png");
        let frame = Frame::new(2, 2, vec![0, 64, 128, 255]).unwrap();
        std::fs::write(&source, frame.encode_png().unwrap()).unwrap();
        let argv = vec![
            "cp".into(),
            source.to_string_lossy().into_owned(),
            "{output}".into(),
        ];
        let mut camera = CommandCamera::new(argv, Duration::from_secs(5)).unwrap();
        assert_eq!(camera.capture().await.unwrap(), frame);
        let silent = vec!["true".into(), "{output}".into()];
        let error = CommandCamera::new(silent, Duration::from_secs(5))
            .unwrap()
            .capture()
            .await
            .unwrap_err();
        assert!(error.to_string().contains("wrote no image"), "{error}");
        let failing = vec![
            "sh".into(),
            "-c".into(),
            "echo no camera >&2; exit 1".into(),
            "{output}".into(),
        ];
        let error = CommandCamera::new(failing, Duration::from_secs(5))
            .unwrap()
            .capture()
            .await
            .unwrap_err();
        assert!(error.to_string().contains("no camera"), "{error}");
    }
}
