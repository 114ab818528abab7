//! The folder camera: the newest image in a folder that a camera's own software writes to.
//! After each move it waits for an image newer than the last one it returned.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::Frame;

use super::{Camera, decode_image, report_saturation};

const IMAGE_EXTENSIONS: [&str; 5] = ["png", "jpg", "jpeg", "tif", "tiff"];

pub struct FolderCamera {
    path: PathBuf,
    timeout: Duration,
    last: Option<(PathBuf, SystemTime)>,
}

impl FolderCamera {
    pub fn new(path: PathBuf, timeout: Duration) -> anyhow::Result<Self> {
        if !path.is_dir() {
            bail!(
                "camera folder {} does not exist or is not a folder",
                path.display()
            );
        }
        Ok(Self {
            path,
            timeout,
            last: None,
        })
    }
}

/// The newest image file in `folder` and its modification time.
fn newest_image(folder: &Path) -> anyhow::Result<Option<(PathBuf, SystemTime)>> {
    let mut newest: Option<(PathBuf, SystemTime)> = None;
    for entry in
        std::fs::read_dir(folder).with_context(|| format!("cannot list {}", folder.display()))?
    {
        let entry = entry?;
        let path = entry.path();
        let is_image = path
            .extension()
            .and_then(|e| e.to_str())
            .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()));
        if !is_image {
            continue;
        }
        let modified = entry.metadata()?.modified()?;
        if newest.as_ref().is_none_or(|(_, time)| modified > *time) {
            newest = Some((path, modified));
        }
    }
    Ok(newest)
}

#[async_trait]
impl Camera for FolderCamera {
    async fn capture(&mut self) -> anyhow::Result<Frame> {
        let started = tokio::time::Instant::now();
        loop {
            if let Some((path, modified)) = newest_image(&self.path)? {
                let is_new = self.last.as_ref().is_none_or(|(last_path, last_time)| {
                    modified > *last_time || path != *last_path
                });
                if is_new {
                    // Give the writer a moment to finish the file.
                    tokio::time::sleep(Duration::from_millis(100)).await;
                    let frame = decode_image(&path)?;
                    self.last = Some((path, modified));
                    report_saturation(&self.describe(), &frame);
                    return Ok(frame);
                }
            }
            if started.elapsed() > self.timeout {
                bail!(
                    "no new image appeared in {} within {:?}",
                    self.path.display(),
                    self.timeout
                );
            }
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
    }

    fn describe(&self) -> String {
        format!("folder camera {}", self.path.display())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn returns_each_new_image_once_and_times_out_without_one() {
        let dir = tempfile::tempdir().unwrap();
        let mut camera =
            FolderCamera::new(dir.path().to_owned(), Duration::from_millis(400)).unwrap();
        let first = Frame::new(16, 16, vec![1; 256]).unwrap();
        std::fs::write(dir.path().join("0001.png"), first.encode_png().unwrap()).unwrap();
        assert_eq!(camera.capture().await.unwrap(), first);
        let error = camera.capture().await.unwrap_err().to_string();
        assert!(error.contains("no new image"), "{error}");
        tokio::time::sleep(Duration::from_millis(20)).await;
        let second = Frame::new(16, 16, vec![3; 256]).unwrap();
        std::fs::write(dir.path().join("0002.png"), second.encode_png().unwrap()).unwrap();
        assert_eq!(camera.capture().await.unwrap(), second);
        assert!(FolderCamera::new(dir.path().join("missing"), Duration::from_secs(1)).is_err());
    }

    #[tokio::test]
    async fn captures_the_jpeg_and_tiff_files_it_watches_for() {
        let dir = tempfile::tempdir().unwrap();
        let mut camera =
            FolderCamera::new(dir.path().to_owned(), Duration::from_millis(400)).unwrap();
        let bright = image::GrayImage::from_pixel(16, 16, image::Luma([200]));
        for (index, (name, format)) in [
            ("0001.tiff", image::ImageFormat::Tiff),
            ("0002.JPG", image::ImageFormat::Jpeg),
            ("0003.tif", image::ImageFormat::Tiff),
            ("0004.jpeg", image::ImageFormat::Jpeg),
        ]
        .into_iter()
        .enumerate()
        {
            tokio::time::sleep(Duration::from_millis(20)).await;
            bright
                .save_with_format(dir.path().join(name), format)
                .unwrap();
            let frame = camera.capture().await.unwrap();
            assert_eq!((frame.width(), frame.height()), (16, 16), "{name}");
            assert!(
                frame.pixels().iter().all(|&p| p.abs_diff(200) <= 2),
                "{name} (capture {index}): {:?}",
                frame.pixels()
            );
        }
    }
}
