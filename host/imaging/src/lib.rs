//! Image analysis for calibration, bench scoring and the image-only agent: a frame's light
//! ([`Picture`]) less what stays put ([`Backdrop`]), its beams ([`find_beams`]), a beam's core
//! ([`core_centre`]), and what changed between frames ([`changes()`], [`scene_shift`]).

mod backdrop;
mod beams;
mod cells;
mod changes;
mod core;
mod gaussian;
mod noise;
#[cfg(test)]
mod photo_tests;
mod picture;
mod register;
#[cfg(any(test, feature = "synthetic"))]
pub mod synthetic;
#[cfg(test)]
mod tests;
mod tuning;

pub use backdrop::Backdrop;
pub use beams::{Beam, find_beams};
pub use changes::{Changes, changes, registered_changes, registered_changes_sized};
pub use core::{core_centre, core_radius};
pub use gaussian::GaussianFit;
pub use noise::NoiseMap;
pub use picture::{Picture, median};
pub use register::scene_shift;

/// The beam with the most light.
pub fn strongest(beams: &[Beam]) -> Option<&Beam> {
    beams.iter().max_by(|a, b| a.signal.total_cmp(&b.signal))
}

/// The beam nearest to `point`.
pub fn nearest(beams: &[Beam], point: [f64; 2]) -> Option<&Beam> {
    beams.iter().min_by(|a, b| {
        let d = |s: &Beam| (s.centre[0] - point[0]).hypot(s.centre[1] - point[1]);
        d(a).total_cmp(&d(b))
    })
}
