//! `optalign._native`: the Rust side of the Python package, built on the `optalign` host
//! library: the simulated episodes behind the Gymnasium environments (one at a time, or a
//! batch stepped on all cores), the controller client, a simulated controller to try it
//! on, a simulated rig's camera, runs and benches, and runs carried out by a Bluesky
//! plan. The Python modules around it add the Gymnasium spaces, the Bluesky devices and
//! friendlier signatures.

mod alignment;
mod camera;
mod controller;
mod episode;
mod errors;
mod peer;
mod runs;
mod runtime;
mod stepper;
mod vector;

use pyo3::prelude::*;

#[pymodule]
fn _native(module: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = module.py();
    module.add_class::<episode::Episode>()?;
    module.add_class::<vector::VectorEpisodes>()?;
    module.add_class::<controller::Controller>()?;
    module.add_class::<peer::SimulatedPeer>()?;
    module.add_class::<camera::SimCamera>()?;
    module.add_class::<alignment::Alignment>()?;
    module.add_function(wrap_pyfunction!(runs::run_json, module)?)?;
    module.add_function(wrap_pyfunction!(runs::bench_json, module)?)?;
    module.add("ControllerError", py.get_type::<errors::ControllerError>())?;
    module.add(
        "ControllerRefused",
        py.get_type::<errors::ControllerRefused>(),
    )?;
    module.add(
        "ControllerTimeout",
        py.get_type::<errors::ControllerTimeout>(),
    )?;
    module.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
