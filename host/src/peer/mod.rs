//! The simulated firmware peer: the real firmware core (`optalign-firmware`) on simulated
//! mount mechanics, served over TCP and a pseudo-terminal exactly as a board serves it.
//!
//! The mechanics add what a real mount does to the motor's steps (a gear dead band, lost
//! steps, a binding region), so backlash compensation, limits and faults behave as they
//! will on hardware; the true shaft positions are hidden truth for the optical scenes.

mod bench;
mod clock;
mod core;
mod mechanics;
pub mod registry;
mod server;
mod state_file;

pub use bench::{Bench, ExecutionLog, PositionAudit, SharedBench};
pub use clock::{SimClock, TimeMode};
pub use core::{PeerCore, PeerOptions};
pub use mechanics::{MechanicsOptions, StallRegion};
pub use server::SimPeer;
pub use state_file::StateFiles;
