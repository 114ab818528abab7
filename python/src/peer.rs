//! `SimulatedPeer`: a simulated motor controller (the firmware core on simulated mounts,
//! as `optalign peer` serves it) listening on a loopback port, so that scripts and tests
//! can try the controller client without hardware.

use std::path::PathBuf;
use std::sync::Arc;

use optalign::peer::{MechanicsOptions, PeerOptions, SimPeer, TimeMode};
use optalign::rig::{rig_axis_config, rig_peer_options};
use optalign_protocol::{Command, PeerMessage, Reply};
use pyo3::prelude::*;
use tokio::runtime::Runtime;

use crate::errors::{failed, invalid};
use crate::runtime;
use crate::stepper::{load_scenario, parse_task};

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
        let options = PeerOptions {
            axes,
            key,
            mechanics: MechanicsOptions {
                backlash,
                ..MechanicsOptions::default()
            },
            time: TimeMode::Scaled(check_scale(time_scale)?),
            ..PeerOptions::default()
        };
        Self::serve(py, &options, port)
    }

    /// The simulated controller of `task`'s rig for `seed`, as `optalign run --sim` moves
    /// it: the scenario's mounts (backlash, pitch error, hysteresis, lost steps drawn for
    /// the seed) and its axis configuration. `time_scale=None` runs on instant time: a
    /// move ends as soon as it is sent.
    #[staticmethod]
    #[pyo3(signature = (task, seed, scenario=None, key=None, time_scale=None, port=0))]
    fn for_rig(
        py: Python<'_>,
        task: &str,
        seed: u64,
        scenario: Option<PathBuf>,
        key: Option<String>,
        time_scale: Option<f64>,
        port: u16,
    ) -> PyResult<Self> {
        let task = parse_task(task).map_err(invalid)?;
        let scenario = load_scenario(scenario).map_err(invalid)?;
        let axes = u8::try_from(task.axes()).map_err(invalid)?;
        let options = PeerOptions {
            key,
            time: match time_scale {
                None => TimeMode::Instant,
                Some(scale) => TimeMode::Scaled(check_scale(scale)?),
            },
            ..rig_peer_options(axes, &scenario.mount, seed)
        };
        let peer = Self::serve(py, &options, port)?;
        for axis in 0..axes {
            let current = match peer.serial(Command::GetConfig { axis })? {
                Reply::Config(config) => config,
                other => {
                    return Err(failed(anyhow::anyhow!(
                        "unexpected reply to GetConfig: {other:?}"
                    )));
                }
            };
            let config = rig_axis_config(&scenario.mount, current);
            peer.serial(Command::SetConfig { axis, config })?;
        }
        Ok(peer)
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

impl SimulatedPeer {
    /// Starts the peer `options` describe on a loopback port (`0`: a free one).
    fn serve(py: Python<'_>, options: &PeerOptions, port: u16) -> PyResult<Self> {
        let runtime = runtime::background()?;
        let (peer, address) = py
            .detach(|| {
                runtime.block_on(async {
                    let peer = SimPeer::start(options)?;
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

    /// Runs `command` as over the serial link (trusted); the controller's reply.
    fn serial(&self, command: Command) -> PyResult<Reply> {
        let _guard = self.runtime.enter();
        self.peer
            .serial_request(command)
            .into_iter()
            .find_map(|message| match message {
                PeerMessage::Reply { reply, .. } => Some(reply),
                _ => None,
            })
            .ok_or_else(|| failed(anyhow::anyhow!("the simulated controller did not answer")))
            .and_then(|reply| match reply {
                Reply::Error(error) => Err(failed(anyhow::anyhow!(
                    "the simulated controller refused: {error}"
                ))),
                reply => Ok(reply),
            })
    }

    /// The peer itself, for a simulated camera watching its mounts.
    pub fn shared(&self) -> Arc<SimPeer> {
        self.peer.clone()
    }
}

fn check_scale(time_scale: f64) -> PyResult<f64> {
    if time_scale.is_finite() && time_scale > 0.0 {
        Ok(time_scale)
    } else {
        Err(invalid(format!(
            "time_scale must be a positive number (1 = real time), got {time_scale}"
        )))
    }
}

impl Drop for SimulatedPeer {
    fn drop(&mut self) {
        self.peer.shutdown();
    }
}
