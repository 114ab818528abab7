//! Calibration of a bench from its camera: the motor-to-pixel response of a mirror and the
//! backlash of an axis, with the fits and charts behind them, the beam an axis moves told
//! by the frames' difference, and the checks that refuse a fit that cannot be trusted.

pub mod backlash;
mod chart;
pub mod fit;
pub mod response;
pub(crate) mod track;
pub mod trust;

pub use backlash::{BacklashReport, calibrate_backlash};
pub use chart::{write_backlash_chart, write_response_chart};
pub use response::{ResponsePoint, ResponseScan, calibrate_response, mirror_axes};
