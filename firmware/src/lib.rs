//! optalign firmware core: motion planning, backlash compensation, soft limits,
//! persistence and the command dispatcher of a motor controller.
//!
//! Hardware independent and allocation free: the board image (Pico W) and the host's
//! simulated peer both embed a [`Controller`] and feed it requests, time and a
//! [`StepDriver`]. The controller never blocks and never panics on any input.
//!
//! How an embedder drives it: each open connection is a [`Connection`], which decodes,
//! checks and encodes its frames, tells when it is closed and reaches the controller
//! through the embedder's [`Port`]; network connections get their places from an
//! [`admission::Admissions`] table. Underneath, what a `Connection` and its `Port` do:
//! - every decoded request goes to [`Controller::handle`], whose `out` receives exactly one
//!   message, the reply, for that session (or to [`Controller::begin`] and
//!   [`Controller::finish`], with the request's cryptography run between them outside the
//!   embedder's lock on the controller: [`crypto`]);
//! - frames are decoded against the session's [`Session::inbound`] (on an authenticated
//!   network session only sealed frames pass); a frame that could not be decoded or was
//!   refused goes to [`Controller::link_error`];
//! - once a session authenticated, [`Session::take_sealer`] gives the sealer for every
//!   frame sent to it from then on (the reply that confirmed authentication included),
//!   notifications too;
//! - when a connection ends, its session goes to [`Controller::end_session`], which
//!   releases control of the motors if that session held it;
//! - [`Controller::poll`] runs whenever [`Controller::next_deadline_us`] is due (and may run
//!   more often); its `out` receives the notifications meant for *every* session
//!   (`MoveFinished`, `Fault`), which the embedder broadcasts. Notifications raised while
//!   handling a request (an emergency stop, a move replaced before it began) are queued and
//!   delivered by the next `poll`; `next_deadline_us` is then due at once.
#![cfg_attr(not(test), no_std)]

pub mod admission;
mod axis;
mod backoff;
#[cfg(feature = "_embassy")]
pub mod board;
pub mod config;
pub mod connection;
mod control;
mod controller;
pub mod crypto;
mod dispatch;
pub mod driver;
pub mod gear;
pub mod mark;
mod motion;
pub mod nonce;
mod outcomes;
pub mod path;
pub mod ramp;
pub mod record;
mod replay;
pub mod session;
#[cfg(any(test, feature = "sim"))]
pub mod sim;
mod slots;
pub mod storage;
#[cfg(test)]
mod tests;
pub mod timeline;

pub use connection::{Connection, Deadlines, Port, Received};
pub use controller::{BoardInfo, Controller};
pub use crypto::{Done, Work};
pub use driver::{StepDirection, StepDriver, half_step_coils};
pub use session::{LinkKind, RngSource, Session};
pub use storage::{RamStorage, Storage, StorageError};
