//! The HTTP camera: GETs one image (PNG, JPEG or TIFF) from a URL per capture, for network
//! cameras with a snapshot URL and for the rehearsal bench (`optalign peer --scene`).

use std::time::Duration;

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::Frame;

use super::{Camera, decode_image_bytes, report_saturation};

/// The largest image accepted, bytes (a 16-bit 8K TIFF is about 66 MB).
const MAX_IMAGE_BYTES: usize = 128 << 20;

pub struct HttpCamera {
    url: String,
    client: reqwest::Client,
}

impl HttpCamera {
    pub fn new(url: String, timeout: Duration) -> anyhow::Result<Self> {
        let client = crate::lab::http::bounded_client(timeout)?;
        Ok(Self { url, client })
    }
}

#[async_trait]
impl Camera for HttpCamera {
    async fn capture(&mut self) -> anyhow::Result<Frame> {
        let response = self
            .client
            .get(&self.url)
            .send()
            .await
            .with_context(|| format!("camera at {} did not answer", self.url))?;
        let status = response.status();
        if !status.is_success() {
            let body = response.text().await.unwrap_or_default();
            bail!(
                "camera at {} refused the capture: {status} {}",
                self.url,
                body.trim()
            );
        }
        if let Some(length) = response.content_length() {
            anyhow::ensure!(
                length as usize <= MAX_IMAGE_BYTES,
                "camera at {} sent {length} bytes, more than the {MAX_IMAGE_BYTES} an image may have",
                self.url
            );
        }
        let bytes = response
            .bytes()
            .await
            .with_context(|| format!("camera at {} broke off the image", self.url))?;
        anyhow::ensure!(
            bytes.len() <= MAX_IMAGE_BYTES,
            "camera at {} sent {} bytes, more than the {MAX_IMAGE_BYTES} an image may have",
            self.url,
            bytes.len()
        );
        let frame = decode_image_bytes(&bytes, &self.url)?;
        report_saturation(&self.describe(), &frame);
        Ok(frame)
    }

    fn describe(&self) -> String {
        format!("HTTP camera {}", self.url)
    }
}

#[cfg(test)]
mod tests {
    use axum::Router;
    use axum::http::StatusCode;
    use axum::routing::get;

    use super::*;

    async fn serve(app: Router) -> String {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let address = listener.local_addr().unwrap();
        tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
        format!("http://{address}")
    }

    #[tokio::test]
    async fn reads_an_image_and_says_why_when_it_cannot() {
        let frame = Frame::new(16, 16, (0..=255).collect()).unwrap();
        let png = frame.encode_png().unwrap();
        let base = serve(
            Router::new()
                .route("/ok", get(move || async move { png.clone() }))
                .route(
                    "/busy",
                    get(|| async { (StatusCode::SERVICE_UNAVAILABLE, "exposing") }),
                )
                .route("/text", get(|| async { "not an image" })),
        )
        .await;
        let timeout = Duration::from_secs(5);
        let mut camera = HttpCamera::new(format!("{base}/ok"), timeout).unwrap();
        assert_eq!(camera.capture().await.unwrap().pixels(), frame.pixels());
        let mut camera = HttpCamera::new(format!("{base}/busy"), timeout).unwrap();
        let error = format!("{:#}", camera.capture().await.unwrap_err());
        assert!(
            error.contains("503") && error.contains("exposing"),
            "{error}"
        );
        let mut camera = HttpCamera::new(format!("{base}/text"), timeout).unwrap();
        let error = format!("{:#}", camera.capture().await.unwrap_err());
        assert!(
            error.contains("is not a PNG, JPEG or TIFF image"),
            "{error}"
        );
    }
}
