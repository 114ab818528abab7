//! `SimulatedPeer`: a simulated motor controller (the firmware core on simulated mounts,
//! as `optalign peer` serves it) listening on a loopback port, so that scripts and tests
//! can try the controller client without hardware.

use std::sync::Arc;

use optalign::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};
use pyo3::prelude::*;
use tokio::runtime::Runtime;

use crate::errors::{failed, invalid};
use crate::runtime;

/// A running simulated controller; it stops when the object is dropped or closed.
#[pyclass(module = "optalign._native")]
pub struct SimulatedPeer {
    peer: Arc<SimPeer>,
    url: String,
    runtime: Runtime,
}

#[pymethods]
impl SimulatedPeer {
    #[new]
    #[pyo3(signature = (axes=4, key=None, backlash=0, time_scale=1.0, port=0))]
    fn new(
        py: Python<'_>,
        axes: u8,
        key: Option<String>,
        backlash: u32,
        time_scale: f64,
        port: u16,
    ) -> PyResult<Self> {
        if !(time_scale.is_finite() && time_scale > 0.0) {
            return Err(invalid(format!(
                "time_scale must be a positive number (1 = real time), got {time_scale}"
            )));
        }
        let options = PeerOptions {
            axes,
            key,
            mechanics: MechanicsOptions {
                backlash,
                ..MechanicsOptions::default()
            },
            time: TimeMode::Scaled(time_scale),
            ..PeerOptions::default()
        };
        let runtime = runtime::background()?;
        let (peer, address) = py
            .detach(|| {
                runtime.block_on(async {
                    let peer = SimPeer::start(&options)?;
                    let address = peer
                        .listen_tcp(std::net::SocketAddr::from(([127, 0, 0, 1], port)))
                        .await?;
                    anyhow::Ok((peer, address))
                })
            })
            .map_err(failed)?;
        Ok(Self {
            peer,
            url: format!("tcp://{address}"),
            runtime,
        })
    }

    /// Where clients reach it: `tcp://127.0.0.1:PORT`.
    #[getter]
    fn url(&self) -> String {
        self.url.clone()
    }

    /// True shaft positions of the simulated mounts (what the optics would see).
    fn shaft_positions(&self) -> Vec<i32> {
        self.peer.shaft_positions()
    }

    /// Stops serving; connected clients see the link drop.
    fn close(&self) {
        let _guard = self.runtime.enter();
        self.peer.shutdown();
    }
}

impl Drop for SimulatedPeer {
    fn drop(&mut self) {
        self.peer.shutdown();
    }
}
