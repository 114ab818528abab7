//! The lab: rig files, cameras, camera movers, the lab rig that runs tasks on a real bench,
//! bench scoring without hidden truth, calibration from the camera, and the rehearsal
//! bench a simulated peer serves across processes, and positions found again from the
//! camera after a power cut.

pub mod calibrate;
pub mod calibration;
pub mod camera;
mod command;
mod http;
pub mod mover;
pub mod rehearsal;
pub mod rezero;
pub mod rig;
pub mod rigfile;
mod scoring;

pub use rig::LabRig;
pub use rigfile::RigFile;
pub use scoring::{ErrorBasis, error_basis};
