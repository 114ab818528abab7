//! The rehearsal bench: a simulated peer that is the whole bench. Besides the motor
//! protocol it serves, on a loopback HTTP port, the camera's frames rendered from its own
//! true shafts (`GET /frame`, a PNG taken when asked) and the relay's camera moves
//! (`POST /station` with `{"station": "C3"}`, answered once the camera is placed), so a
//! rig file with `camera.kind = "http"` and `mover.kind = "http"` drives it from other
//! processes exactly as it drives a bench. Task axis `i` is the peer's axis `i`; axes past
//! the task's move no mirror (a motor that is not wired).

use std::net::SocketAddr;
use std::path::Path;
use std::sync::Arc;

use anyhow::Context;
use axum::extract::State;
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use optalign_optics::seeds::{cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{Cavity, Michelson, Relay, Station};
use serde::Deserialize;
use tokio::sync::Mutex;

use super::camera::{Camera, SimCamera, SimScene, SimView};
use super::rigfile::{AxisRoute, task_axis_names};
use crate::peer::SimPeer;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// The task's simulated scene for `seed`, with the scenario file's parameters (defaults
/// when `scenario` is `None`).
pub fn sim_view(
    task: TaskKind,
    scenario: Option<&Path>,
    seed: u64,
) -> anyhow::Result<Arc<SimView>> {
    let scenario = ScenarioFile::load_or_default(scenario)?;
    let scene = match task {
        TaskKind::Michelson => SimScene::Michelson(Michelson::new(
            scenario.michelson.clone(),
            michelson_offsets(&scenario.michelson, seed),
        )?),
        TaskKind::Cavity => SimScene::Cavity(Cavity::new(
            scenario.cavity.clone(),
            cavity_offsets(&scenario.cavity, seed),
        )?),
        TaskKind::Relay => SimScene::Relay(Box::new(Relay::new(
            scenario.relay.clone(),
            relay_offsets(&scenario.relay, seed)?,
        )?)),
    };
    Ok(Arc::new(SimView::new(scene, seed)))
}

/// The number of axes the task's scene is wired to (peer axes 0..n).
pub fn scene_axes(task: TaskKind) -> usize {
    task_axis_names(task).len()
}

#[derive(Clone)]
struct Service {
    camera: Arc<Mutex<SimCamera>>,
    view: Arc<SimView>,
}

/// Serves the scene of `task` on `peer`'s shafts at `listen`; returns the bound address.
/// The server runs until the process ends.
pub async fn serve(
    listen: SocketAddr,
    peer: Arc<SimPeer>,
    view: Arc<SimView>,
    task: TaskKind,
) -> anyhow::Result<SocketAddr> {
    let routes = (0..scene_axes(task))
        .map(|axis| AxisRoute {
            controller: 0,
            axis: axis as u8,
            sign: 1,
        })
        .collect();
    let service = Service {
        camera: Arc::new(Mutex::new(SimCamera::new(view.clone(), vec![peer], routes))),
        view,
    };
    let app = Router::new()
        .route("/frame", get(frame))
        .route("/station", post(station))
        .with_state(service);
    let listener = tokio::net::TcpListener::bind(listen)
        .await
        .with_context(|| format!("cannot serve the rehearsal camera on {listen}"))?;
    let bound = listener.local_addr()?;
    tokio::spawn(async move {
        if let Err(error) = axum::serve(listener, app).await {
            tracing::error!(%error, "the rehearsal camera server stopped");
        }
    });
    Ok(bound)
}

async fn frame(State(service): State<Service>) -> Response {
    let frame = service.camera.lock().await.capture().await;
    match frame.and_then(|frame| Ok(frame.encode_png()?)) {
        Ok(bytes) => (
            [
                (header::CONTENT_TYPE, "image/png"),
                (header::CACHE_CONTROL, "no-store"),
            ],
            bytes,
        )
            .into_response(),
        Err(error) => (StatusCode::INTERNAL_SERVER_ERROR, format!("{error:#}")).into_response(),
    }
}

#[derive(Deserialize)]
struct StationRequest {
    station: String,
}

async fn station(State(service): State<Service>, Json(request): Json<StationRequest>) -> Response {
    match request.station.parse::<Station>() {
        Ok(station) => {
            service.view.place(station);
            StatusCode::OK.into_response()
        }
        Err(error) => (
            StatusCode::UNPROCESSABLE_ENTITY,
            format!("station {:?}: {error}", request.station),
        )
            .into_response(),
    }
}

/// A rig file for the rehearsal bench: the peer at `controller`, the camera (and, for the
/// relay, the camera mover) at `camera`, every task axis on the peer's axis of the same
/// number, no settling waits.
pub fn rig_file_text(task: TaskKind, controller: SocketAddr, camera: SocketAddr) -> String {
    let mut text = format!(
        "# The rehearsal bench of `optalign peer --scene {task}`: edit it as your bench's.\n\
         task = \"{task}\"\n\n[[controller]]\nname = \"rehearsal\"\nurl = \"tcp://{controller}\"\n\n[axes]\n"
    );
    for (axis, name) in task_axis_names(task).iter().enumerate() {
        text.push_str(&format!(
            "{name} = {{ controller = \"rehearsal\", axis = {axis} }}\n"
        ));
    }
    text.push_str(&format!(
        "\n[camera]\nkind = \"http\"\nurl = \"http://{camera}/frame\"\n"
    ));
    if task == TaskKind::Relay {
        text.push_str(&format!(
            "\n[mover]\nkind = \"http\"\nurl = \"http://{camera}/station\"\n"
        ));
    }
    text.push_str("\n[settle]\nafter_motor_s = 0\nafter_camera_s = 0\n");
    text
}
