//! The monitor's HTTP server (axum): the page, a server-sent event stream of the run's
//! view, the frames and their detected beams on request, and the pause and stop commands;
//! for a bench, the matrix page and its progress stream. Every route sits behind the
//! access guard.

use std::convert::Infallible;
use std::net::SocketAddr;
use std::time::Duration;

use anyhow::Context;
use axum::extract::{Path, Query, State};
use axum::http::{StatusCode, Uri, header};
use axum::response::sse::{Event, KeepAlive, Sse};
use axum::response::{Html, IntoResponse, Redirect, Response};
use axum::routing::{get, post};
use axum::{Json, Router, middleware};
use futures::Stream;
use serde::Deserialize;
use tokio::task::JoinHandle;

use super::access::{Access, guard};
use super::frames::ShownFrame;
use super::hub::Hub;
use super::run::{ControlError, RunMonitor};

const RUN_PAGE: &str = include_str!("page.html");
const MATRIX_PAGE: &str = include_str!("matrix.html");

/// Updates to one page are sent at most this often; states in between are skipped.
const UPDATE_INTERVAL: Duration = Duration::from_millis(100);
/// How often the matrix page's progress is sent.
const MATRIX_INTERVAL: Duration = Duration::from_millis(500);

/// The routes of a monitor over `hub`, guarded by `access`.
pub fn router(hub: Hub, access: Access) -> Router {
    Router::new()
        .route("/", get(front))
        .route("/matrix/events", get(matrix_events))
        .route("/run/{id}/", get(run_page))
        .route("/run/{id}/events", get(run_events))
        .route("/run/{id}/frame/{evaluation}", get(frame_png))
        .route("/run/{id}/beams/{evaluation}", get(frame_beams))
        .route("/run/{id}/pause", post(pause))
        .route("/run/{id}/step", post(step))
        .route("/run/{id}/stop", post(stop))
        .with_state(hub)
        .layer(middleware::from_fn_with_state(access, guard))
}

/// A running monitor server; it stops when dropped.
pub struct MonitorServer {
    pub address: SocketAddr,
    pub url: String,
    task: JoinHandle<()>,
}

impl MonitorServer {
    /// Stops serving after open pages have had the time to receive the final state.
    pub async fn close(self) {
        tokio::time::sleep(UPDATE_INTERVAL * 10).await;
    }
}

impl Drop for MonitorServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Listens on `address` and serves `hub` in the background.
pub async fn start(address: SocketAddr, hub: Hub, access: Access) -> anyhow::Result<MonitorServer> {
    let listener = tokio::net::TcpListener::bind(address)
        .await
        .with_context(|| format!("the monitor cannot listen on {address}"))?;
    let address = listener.local_addr()?;
    let url = access.url(address);
    let app = router(hub, access);
    let task = tokio::spawn(async move {
        if let Err(error) = axum::serve(listener, app).await {
            tracing::warn!(%error, "the monitor server stopped");
        }
    });
    Ok(MonitorServer { address, url, task })
}

/// A request the monitor cannot serve, with why.
struct Refusal(StatusCode, String);

impl IntoResponse for Refusal {
    fn into_response(self) -> Response {
        (self.0, format!("{}\n", self.1)).into_response()
    }
}

fn run_of(hub: &Hub, id: usize) -> Result<RunMonitor, Refusal> {
    hub.run(id)
        .ok_or_else(|| Refusal(StatusCode::NOT_FOUND, format!("no run {id} here")))
}

/// The answer to an operator's command.
fn commanded(result: Result<(), ControlError>) -> Result<Response, Refusal> {
    result
        .map(|()| StatusCode::NO_CONTENT.into_response())
        .map_err(|error| Refusal(StatusCode::CONFLICT, error.to_string()))
}

/// The front page: the matrix for a bench, else the one run's page.
async fn front(State(hub): State<Hub>, uri: Uri) -> Response {
    if hub.is_matrix() {
        return Html(MATRIX_PAGE).into_response();
    }
    let query = uri.query().map(|q| format!("?{q}")).unwrap_or_default();
    Redirect::to(&format!("run/0/{query}")).into_response()
}

async fn run_page(State(hub): State<Hub>, Path(id): Path<usize>) -> Result<Response, Refusal> {
    run_of(&hub, id)?;
    Ok(Html(RUN_PAGE).into_response())
}

/// The run's view as server-sent events: everything first, then each change with only the
/// steps the page does not have, at most every [`UPDATE_INTERVAL`].
async fn run_events(State(hub): State<Hub>, Path(id): Path<usize>) -> Result<Response, Refusal> {
    let receiver = run_of(&hub, id)?.subscribe();
    let stream = futures::stream::unfold(
        (receiver, 0usize, true),
        |(mut receiver, known, first)| async move {
            if !first {
                tokio::time::sleep(UPDATE_INTERVAL).await;
                receiver.changed().await.ok()?;
            }
            let (update, known) = {
                let view = receiver.borrow_and_update();
                (view.update_since(known), view.steps.len())
            };
            let event = Event::default().event("update").data(update.to_string());
            Some((Ok::<_, Infallible>(event), (receiver, known, false)))
        },
    );
    Ok(sse(stream))
}

async fn matrix_events(State(hub): State<Hub>) -> Response {
    let stream = futures::stream::unfold(hub, |hub| async move {
        let data = serde_json::to_string(&hub.matrix_view()).unwrap_or_default();
        let event = Event::default().event("matrix").data(data);
        tokio::time::sleep(MATRIX_INTERVAL).await;
        Some((Ok::<_, Infallible>(event), hub))
    });
    sse(stream)
}

fn sse(stream: impl Stream<Item = Result<Event, Infallible>> + Send + 'static) -> Response {
    Sse::new(stream)
        .keep_alive(KeepAlive::default())
        .into_response()
}

/// Encodes (and searches) a frame off the async threads.
async fn shown_frame(hub: &Hub, id: usize, evaluation: usize) -> Result<ShownFrame, Refusal> {
    let run = run_of(hub, id)?;
    let shown = tokio::task::spawn_blocking(move || run.frames().show(evaluation))
        .await
        .map_err(|error| Refusal(StatusCode::INTERNAL_SERVER_ERROR, error.to_string()))?;
    match shown {
        Ok(Some(shown)) => Ok(shown),
        Ok(None) => Err(Refusal(
            StatusCode::NOT_FOUND,
            format!("frame {evaluation} is neither the newest nor saved"),
        )),
        Err(error) => Err(Refusal(
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("{error:#}"),
        )),
    }
}

async fn frame_png(
    State(hub): State<Hub>,
    Path((id, evaluation)): Path<(usize, usize)>,
) -> Result<Response, Refusal> {
    let shown = shown_frame(&hub, id, evaluation).await?;
    Ok((
        [
            (header::CONTENT_TYPE, "image/png"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        shown.png.as_ref().clone(),
    )
        .into_response())
}

async fn frame_beams(
    State(hub): State<Hub>,
    Path((id, evaluation)): Path<(usize, usize)>,
) -> Result<Response, Refusal> {
    let shown = shown_frame(&hub, id, evaluation).await?;
    Ok(Json(shown.beams.as_ref().clone()).into_response())
}

#[derive(Deserialize)]
struct PauseQuery {
    paused: bool,
}

async fn pause(
    State(hub): State<Hub>,
    Path(id): Path<usize>,
    Query(query): Query<PauseQuery>,
) -> Result<Response, Refusal> {
    commanded(run_of(&hub, id)?.set_paused(query.paused))
}

async fn step(State(hub): State<Hub>, Path(id): Path<usize>) -> Result<Response, Refusal> {
    commanded(run_of(&hub, id)?.allow_step())
}

async fn stop(State(hub): State<Hub>, Path(id): Path<usize>) -> Result<Response, Refusal> {
    commanded(run_of(&hub, id)?.request_stop("stopped by the operator from the monitor"))
}
