//! The optalign host library: the controller link, the simulated firmware peer, scenarios,
//! tasks, rigs, policies, the run loop and the command-line front end. The `optalign`
//! binary is a thin wrapper around [`cli`].

pub mod bench;
pub mod bounds;
pub mod cli;
pub mod console;
pub mod flash;
pub use optalign_imaging as imaging;
pub mod lab;
pub mod link;
pub mod logging;
pub mod monitor;
pub mod peer;
pub mod policy;
pub mod rig;
pub mod run;
pub mod scenario;
pub mod task;
