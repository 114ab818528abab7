//! The Python exceptions of the package and the conversions into them.

use optalign::link::ClientError;
use pyo3::create_exception;
use pyo3::exceptions::{PyException, PyRuntimeError, PyValueError};
use pyo3::prelude::*;

create_exception!(
    _native,
    ControllerError,
    PyException,
    "A controller operation failed: the link, the handshake or the controller's answer."
);
create_exception!(
    _native,
    ControllerRefused,
    ControllerError,
    "The controller refused the request; `code` holds the protocol's error code."
);
create_exception!(
    _native,
    ControllerTimeout,
    ControllerError,
    "No answer, or the motion did not end, within the timeout."
);

/// A bad argument: the message says which and why.
pub fn invalid(error: impl std::fmt::Display) -> PyErr {
    PyValueError::new_err(error.to_string())
}

/// A failure inside the simulation or a run, with its whole chain of causes.
pub fn failed(error: anyhow::Error) -> PyErr {
    PyRuntimeError::new_err(format!("{error:#}"))
}

/// A controller failure as the exception that fits it, with the whole message (and the
/// command line's hint, when there is one).
pub fn controller(py: Python<'_>, error: anyhow::Error) -> PyErr {
    let message = format!("{error:#}");
    match error.downcast_ref::<ClientError>() {
        Some(ClientError::Rejected(reply)) => {
            let exception = ControllerRefused::new_err(message);
            match exception.value(py).setattr("code", reply.code.0) {
                Ok(()) => exception,
                Err(cannot_set) => cannot_set,
            }
        }
        Some(
            ClientError::Timeout { .. }
            | ClientError::Deadline { .. }
            | ClientError::MoveTimeout { .. }
            | ClientError::SendTimeout { .. },
        ) => ControllerTimeout::new_err(message),
        _ => ControllerError::new_err(message),
    }
}
