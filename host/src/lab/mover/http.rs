//! The HTTP mover: POSTs `{"station": "C3"}` to a configured URL and waits for a 2xx answer,
//! which the robot arm's server sends once the camera is in place.

use std::time::Duration;

use anyhow::{Context, bail};
use async_trait::async_trait;
use optalign_optics::Station;

use super::CameraMover;

pub struct HttpMover {
    url: String,
    client: reqwest::Client,
}

impl HttpMover {
    pub fn new(url: String, timeout: Duration) -> anyhow::Result<Self> {
        let client = crate::lab::http::bounded_client(timeout)?;
        Ok(Self { url, client })
    }
}

#[async_trait]
impl CameraMover for HttpMover {
    async fn move_to(&mut self, station: Station) -> anyhow::Result<()> {
        let response = self
            .client
            .post(&self.url)
            .json(&serde_json::json!({ "station": station.to_string() }))
            .send()
            .await
            .with_context(|| format!("camera mover at {} did not answer", self.url))?;
        let status = response.status();
        if !status.is_success() {
            let body = response.text().await.unwrap_or_default();
            bail!(
                "camera mover at {} refused {station}: {status} {}",
                self.url,
                body.trim()
            );
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!("HTTP mover {}", self.url)
    }
}

#[cfg(test)]
mod tests {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};

    use super::*;

    /// A one-connection-at-a-time HTTP server: 200 for C3, 409 with a reason otherwise.
    async fn arm() -> (String, tokio::task::JoinHandle<Vec<String>>) {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        let url = format!("http://{}/station", listener.local_addr().unwrap());
        let server = tokio::spawn(async move {
            let mut bodies = Vec::new();
            for _ in 0..2 {
                let (mut socket, _) = listener.accept().await.unwrap();
                let mut request = vec![0u8; 4096];
                let n = socket.read(&mut request).await.unwrap();
                let text = String::from_utf8_lossy(&request[..n]).to_string();
                let body = text.split("\r\n\r\n").nth(1).unwrap_or_default().to_owned();
                let reply = if body.contains("\"C3\"") {
                    "HTTP/1.1 200 OK\r\ncontent-length: 0\r\nconnection: close\r\n\r\n".to_owned()
                } else {
                    "HTTP/1.1 409 Conflict\r\ncontent-length: 11\r\nconnection: close\r\n\r\narm is busy".to_owned()
                };
                socket.write_all(reply.as_bytes()).await.unwrap();
                bodies.push(body);
            }
            bodies
        });
        (url, server)
    }

    #[tokio::test]
    async fn posts_the_station_and_reports_refusals() {
        let (url, server) = arm().await;
        let mut mover = HttpMover::new(url, Duration::from_secs(5)).unwrap();
        mover.move_to(Station::C3).await.unwrap();
        let error = mover.move_to(Station::C2).await.unwrap_err().to_string();
        assert!(
            error.contains("refused C2") && error.contains("409") && error.contains("arm is busy"),
            "{error}"
        );
        let bodies = server.await.unwrap();
        assert_eq!(bodies[0], r#"{"station":"C3"}"#);
    }
}
