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

    /// A command camera whose command copies `frame`, written as PNG to `source`.
    fn copying(frame: &Frame, source: &std::path::Path) -> CommandCamera {
        std::fs::write(source, frame.encode_png().unwrap()).unwrap();
        let argv = vec![
            "cp".into(),
            source.to_string_lossy().into_owned(),
            "{output}".into(),
        ];
        CommandCamera::new(argv, Duration::from_secs(5)).unwrap()
    }

    #[tokio::test]
    async fn reads_what_the_command_wrote_and_explains_failures() {
        let dir = tempfile::tempdir().unwrap();
        let frame = Frame::new(16, 16, (0..=255).collect()).unwrap();
        let mut camera = copying(&frame, &dir.path().join("beam.png"));
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

    /// The strongest beam's centre in what the command camera reads from `frame`'s PNG.
    async fn centre_through_the_camera(frame: &Frame, dir: &std::path::Path) -> [f64; 2] {
        let source = dir.join(format!("scene-{}.png", frame.full_scale()));
        let mut camera = copying(frame, &source);
        let captured = camera.capture().await.unwrap();
        assert_eq!(captured.full_scale(), frame.full_scale());
        assert_eq!(captured.pixels(), frame.pixels());
        let picture = crate::imaging::Picture::new(&captured);
        crate::imaging::find_beams(&picture)[0].centre
    }

    #[tokio::test]
    async fn one_scene_as_8_bit_16_bit_and_12_bit_in_16_files_gives_one_centre() {
        let dir = tempfile::tempdir().unwrap();
        let mut centres = Vec::new();
        for bits in [8, 16, 12] {
            let mut params = optalign_optics::scenario::MichelsonParams::default();
            params.noise.bits = bits;
            let scene = optalign_optics::Michelson::new(params, [900, -700, -1200, 500]).unwrap();
            let frame = scene.render(&[0, 0, 0, 0], 3);
            let full_scale = [(8, 255), (12, 4095), (16, 65535)]
                .into_iter()
                .find(|&(b, _)| b == bits)
                .map(|(_, full)| full)
                .unwrap();
            assert_eq!(frame.full_scale(), full_scale);
            centres.push(centre_through_the_camera(&frame, dir.path()).await);
        }
        for centre in &centres[1..] {
            let apart = (centre[0] - centres[0][0]).hypot(centre[1] - centres[0][1]);
            assert!(apart < 0.5, "centres {centres:?}");
        }
    }

    /// The command camera table docs/lab.md gives as its recipe.
    fn documented_recipe() -> crate::lab::rigfile::CameraSpec {
        let doc = include_str!("../../../../docs/lab.md");
        let block = doc
            .split("<!-- command camera recipe -->")
            .nth(1)
            .and_then(|rest| rest.split("```toml").nth(1))
            .and_then(|rest| rest.split("```").next())
            .expect("docs/lab.md has the command camera recipe");
        let table: toml::Table = toml::from_str(block).unwrap();
        table["camera"].clone().try_into().unwrap()
    }

    #[tokio::test]
    async fn the_documented_ffmpeg_recipe_reads_what_the_tool_writes() {
        let crate::lab::rigfile::CameraSpec::Command {
            mut argv,
            timeout_s,
        } = documented_recipe()
        else {
            panic!("the recipe is not a command camera");
        };
        assert_eq!(argv[0], "ffmpeg");
        let dir = tempfile::tempdir().unwrap();
        let frame = Frame::new(16, 16, (0..=255).rev().collect()).unwrap();
        let source = dir.path().join("grabbed.png");
        std::fs::write(&source, frame.encode_png().unwrap()).unwrap();
        // Stands in for ffmpeg: checks the arguments that matter, then writes one PNG where
        // the last argument says, as ffmpeg does.
        let tool = dir.path().join("ffmpeg");
        std::fs::write(
            &tool,
            format!(
                "#!/bin/sh\nfor last; do :; done\ncase \"$*\" in *'-f video4linux2'*'-i /dev/video0'*'-frames:v 1'*'-pix_fmt gray'*) ;; *) echo \"unexpected: $*\" >&2; exit 2;; esac\ncase \"$last\" in *.png) cp '{}' \"$last\";; *) echo \"not a PNG path: $last\" >&2; exit 3;; esac\n",
                source.display()
            ),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&tool, std::fs::Permissions::from_mode(0o755)).unwrap();
        argv[0] = tool.to_string_lossy().into_owned();
        let mut camera = CommandCamera::new(argv, Duration::from_secs_f64(timeout_s)).unwrap();
        assert_eq!(camera.capture().await.unwrap(), frame);
    }
}
