//! Image analysis shared by calibration, bench scoring and the image-only agent: finding
//! beams in a frame and finding what changed between two frames.

mod beams;
mod gaussian;

pub use beams::{BeamSpot, Changes, changes, find_beams, nearest, saturated_centre};
pub use gaussian::GaussianFit;
