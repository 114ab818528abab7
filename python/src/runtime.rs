//! The async runtimes the blocking Python calls run on.

use pyo3::PyResult;
use pyo3::exceptions::PyRuntimeError;
use tokio::runtime::{Builder, Runtime};

/// A runtime on the calling thread, for simulated episodes (everything, the simulated
/// peer included, runs while a call is under way).
pub fn single_threaded() -> PyResult<Runtime> {
    Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start an async runtime: {e}")))
}

/// A runtime with one worker of its own, for a controller link whose reader keeps
/// listening between calls.
pub fn background() -> PyResult<Runtime> {
    Builder::new_multi_thread()
        .worker_threads(1)
        .enable_all()
        .build()
        .map_err(|e| PyRuntimeError::new_err(format!("cannot start an async runtime: {e}")))
}
