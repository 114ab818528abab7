//! `Controller`: a blocking client of a motor controller (a Pico W board or a simulated
//! peer) for lab scripts. It is the command line's client underneath, with the same access
//! rules: the key comes from the argument or `OPTALIGN_KEY`, a network link without it
//! gets status but no motion, and every refusal carries the controller's message and the
//! command line's hint.

use std::time::Duration;

use anyhow::{Context, bail};
use optalign::cli::axes::check_axes;
use optalign::cli::config::apply_field;
use optalign::cli::connect::{ControllerArgs, DEFAULT_DEADLINE_MS};
use optalign::link::{Client, Endpoint};
use optalign_protocol::{AxisValue, Command, MoveOutcome};
use pyo3::prelude::*;
use tokio::runtime::Runtime;

use crate::errors::{controller as controller_error, invalid};
use crate::runtime;

/// An open link to one controller.
#[pyclass(module = "optalign._native")]
pub struct Controller {
    args: ControllerArgs,
    client: Client,
    runtime: Runtime,
}

impl Controller {
    /// Runs one client operation with the GIL released; failures become the matching
    /// exception.
    fn call<T: Send>(
        &self,
        py: Python<'_>,
        operation: impl AsyncFnOnce(&Client) -> anyhow::Result<T> + Send,
    ) -> PyResult<T> {
        py.detach(|| self.runtime.block_on(operation(&self.client)))
            .map_err(|error| controller_error(py, error))
    }

    /// A refusal or link failure explained the way the command line explains it.
    fn explained(&self, error: optalign::link::ClientError) -> anyhow::Error {
        self.args.explain(error)
    }

    fn axis_values(&self, pairs: Vec<(i64, i64)>) -> PyResult<Vec<AxisValue>> {
        let values = pairs
            .into_iter()
            .map(|(axis, steps)| {
                Ok(AxisValue {
                    axis: u8::try_from(axis)
                        .map_err(|_| invalid(format!("axis {axis} is not an axis number")))?,
                    steps: i32::try_from(steps).map_err(|_| {
                        invalid(format!(
                            "{steps} steps on axis {axis} do not fit in 32 bits"
                        ))
                    })?,
                })
            })
            .collect::<PyResult<Vec<_>>>()?;
        if values.is_empty() {
            return Err(invalid("give at least one axis to move"));
        }
        check_axes(&values, self.client.identity().axes).map_err(invalid)?;
        Ok(values)
    }

    fn run_move(
        &self,
        py: Python<'_>,
        values: Vec<AxisValue>,
        relative: bool,
        timeout: f64,
    ) -> PyResult<(String, Vec<i32>, u32)> {
        let waited = seconds("timeout", timeout)?;
        self.call(py, async |client| {
            let moving = async {
                if relative {
                    client.move_by(&values).await
                } else {
                    client.move_to(&values).await
                }
            };
            let report = tokio::time::timeout(waited, moving)
                .await
                .map_err(|_| {
                    anyhow::Error::new(optalign::link::ClientError::MoveTimeout {
                        endpoint: client.endpoint().clone(),
                        waited,
                    })
                    .context("the motion may still be under way: call stop() or emergency_stop()")
                })?
                .map_err(|e| self.explained(e))?;
            let positions = report
                .positions
                .iter()
                .enumerate()
                .map(|(axis, position)| format!("{axis}={position}"))
                .collect::<Vec<_>>()
                .join(" ");
            if report.outcome != MoveOutcome::Completed {
                bail!("move ended early ({:?}) at {positions}", report.outcome);
            }
            Ok((
                format!("{:?}", report.outcome),
                report.positions,
                report.duration_ms,
            ))
        })
    }
}

fn seconds(name: &str, value: f64) -> PyResult<Duration> {
    Duration::try_from_secs_f64(value)
        .ok()
        .filter(|duration| !duration.is_zero())
        .ok_or_else(|| {
            invalid(format!(
                "{name} must be a positive number of seconds, got {value}"
            ))
        })
}

#[pymethods]
impl Controller {
    #[new]
    #[pyo3(signature = (url, key=None, timeout=1.5))]
    fn new(py: Python<'_>, url: &str, key: Option<String>, timeout: f64) -> PyResult<Self> {
        let endpoint: Endpoint = url.parse().map_err(invalid)?;
        let key = key.or_else(|| std::env::var("OPTALIGN_KEY").ok());
        let args = ControllerArgs {
            controller: endpoint,
            key,
            timeout_ms: seconds("timeout", timeout)?.as_millis().max(1) as u64,
            deadline_ms: DEFAULT_DEADLINE_MS,
        };
        let runtime = runtime::background()?;
        let client = py
            .detach(|| runtime.block_on(args.connect()))
            .map_err(|error| controller_error(py, error))?;
        Ok(Self {
            args,
            client,
            runtime,
        })
    }

    /// The controller's identity and every axis's state, as JSON.
    fn status_json(&self, py: Python<'_>) -> PyResult<String> {
        self.call(py, async |client| {
            let status = client.status().await.map_err(|e| self.explained(e))?;
            let endpoint = client.endpoint().to_string();
            let report =
                optalign::link::report::status_report(&endpoint, &client.identity(), &status);
            Ok(report.to_string())
        })
    }

    /// Moves axes to absolute positions and waits for the motion to end.
    #[pyo3(signature = (targets, timeout=60.0))]
    fn move_to(
        &self,
        py: Python<'_>,
        targets: Vec<(i64, i64)>,
        timeout: f64,
    ) -> PyResult<(String, Vec<i32>, u32)> {
        let values = self.axis_values(targets)?;
        self.run_move(py, values, false, timeout)
    }

    /// Moves axes by relative amounts and waits for the motion to end.
    #[pyo3(signature = (deltas, timeout=60.0))]
    fn move_by(
        &self,
        py: Python<'_>,
        deltas: Vec<(i64, i64)>,
        timeout: f64,
    ) -> PyResult<(String, Vec<i32>, u32)> {
        let values = self.axis_values(deltas)?;
        self.run_move(py, values, true, timeout)
    }

    /// Decelerates every axis to rest.
    fn stop(&self, py: Python<'_>) -> PyResult<()> {
        self.command(py, Command::Stop)
    }

    /// Stops every axis at once, cuts the coils and latches motion off (allowed without
    /// the key).
    fn emergency_stop(&self, py: Python<'_>) -> PyResult<()> {
        self.command(py, Command::EmergencyStop)
    }

    /// Releases the emergency latch.
    fn clear_emergency(&self, py: Python<'_>) -> PyResult<()> {
        self.command(py, Command::ClearEmergency)
    }

    /// One axis's configuration as JSON.
    fn config_json(&self, py: Python<'_>, axis: u8) -> PyResult<String> {
        self.check_axis(axis)?;
        self.call(py, async |client| {
            let config = client
                .get_config(axis)
                .await
                .map_err(|e| self.explained(e))?;
            Ok(serde_json::to_string(&config)?)
        })
    }

    /// Changes fields of one axis's configuration (`key=value` as `optalign config set`
    /// takes them), optionally saving to flash; returns the new configuration as JSON.
    fn set_config_json(
        &self,
        py: Python<'_>,
        axis: u8,
        fields: Vec<String>,
        save: bool,
    ) -> PyResult<String> {
        self.check_axis(axis)?;
        self.call(py, async |client| {
            let mut config = client
                .get_config(axis)
                .await
                .map_err(|e| self.explained(e))?;
            for field in &fields {
                apply_field(&mut config, field)?;
            }
            client
                .command_ok(Command::SetConfig { axis, config })
                .await
                .map_err(|e| self.explained(e))?;
            if save {
                client
                    .command_ok(Command::SaveConfig)
                    .await
                    .map_err(|e| self.explained(e))?;
            }
            serde_json::to_string(&config).context("cannot write the configuration as JSON")
        })
    }

    /// Number of axes the controller drives.
    fn axes(&self) -> u8 {
        self.client.identity().axes
    }

    /// The controller's address.
    fn url(&self) -> String {
        self.client.endpoint().to_string()
    }
}

impl Controller {
    fn command(&self, py: Python<'_>, command: Command) -> PyResult<()> {
        self.call(py, async |client| {
            client
                .command_ok(command)
                .await
                .map_err(|e| self.explained(e))
        })
    }

    fn check_axis(&self, axis: u8) -> PyResult<()> {
        let axes = self.client.identity().axes;
        if axis < axes {
            Ok(())
        } else {
            Err(invalid(format!(
                "unknown axis {axis}: this controller has axes 0..={}",
                axes.saturating_sub(1)
            )))
        }
    }
}
