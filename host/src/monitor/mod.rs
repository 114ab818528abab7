//! The live run monitor: a page in the browser showing what the agent sees and does (the
//! newest frame with the detected beams, the target and the believed against the true
//! positions, the action and its feedback, the policy's words, the error curves, the
//! controllers, the transcript's tail), with pause and an emergency stop; the same page
//! replays a finished run from its folder. The run loop talks to it through
//! [`RunMonitor`]; policies never see it.

mod access;
mod frames;
mod hub;
mod replay;
mod run;
mod server;
mod steps;
mod view;

pub use access::{Access, TOKEN_PARAMETER};
pub use frames::{DetectedBeam, Detections, FrameStore};
pub use hub::{Hub, MatrixView, RunEntry};
pub use replay::load_recorded;
pub use run::{Control, ControlError, RunMonitor};
pub use server::{MonitorServer, router, start};
pub use view::{Mark, MarkKind, RunStatus, RunView, StepView};
