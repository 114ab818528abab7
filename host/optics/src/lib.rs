//! Simulated optical scenes rendered from true motor shaft positions.
//!
//! Three scenes, each pure and deterministic: given the true shaft positions (motor steps per
//! axis) and a frame index, render one 8-bit grayscale camera [`Frame`], and report hidden
//! truth for scoring (never for policies).
//!
//! - [`Michelson`]: two interfering Gaussian beams, 4 axes.
//! - [`Cavity`]: a fixed saturated primary, a dim moving secondary, stationary artefacts, 2 axes.
//! - [`Relay`]: ray tracing through four circular mirrors to one of eight camera stations,
//!   8 axes.
//!
//! Parameters come from a TOML [`Scenario`]; hidden offsets from [`seeds`]. Every scene is
//! aligned exactly when the shafts read the negative of its offsets.

mod cavity;
mod frame;
mod math;
mod michelson;
mod photo;
mod profile;
mod readout;
mod relay;
pub mod scenario;
pub mod seeds;
mod sensor;
mod speckle;

pub use cavity::{Cavity, CavityTruth};
pub use frame::{Frame, FrameError};
pub use math::normal_cdf;
pub use michelson::{Michelson, MichelsonTruth};
pub use relay::{
    CameraPose, MirrorTruth, Relay, RelayTruth, Station, StationTruth, UnknownStation,
};
pub use scenario::{Scenario, ScenarioError};
