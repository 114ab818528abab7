//! Calibration of a bench from its camera: the motor-to-pixel response of a mirror and the
//! backlash of an axis, with the fits and charts behind them.

pub mod backlash;
mod chart;
pub mod fit;
pub mod response;

pub use backlash::{BacklashReport, calibrate_backlash};
pub use chart::{write_backlash_chart, write_response_chart};
pub use response::{ResponsePoint, calibrate_response, mirror_axes};
