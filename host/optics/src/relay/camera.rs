//! The relay's camera stations C1..C8 and the camera's pose at a station, including the small
//! random placement error every move of the camera adds.

use std::f64::consts::TAU;
use std::fmt;
use std::str::FromStr;

use rand::Rng;
use serde::{Deserialize, Serialize};

use crate::scenario::RelayCameraParams;

/// One of the eight calibrated camera stations, two per segment: C1 (near M1) and C2 (just
/// before M2) after M1; C3, C4 after M2; C5, C6 after M3; C7 (near M4) and C8 (farther
/// along the output) after M4.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
pub enum Station {
    /// Near M1, on M1->M2.
    C1,
    /// Just before M2, on M1->M2.
    C2,
    /// Near M2, on M2->M3.
    C3,
    /// Just before M3, on M2->M3.
    C4,
    /// Near M3, on M3->M4.
    C5,
    /// Just before M4, on M3->M4.
    C6,
    /// Near M4, on the output.
    C7,
    /// Farther along the output: the final station.
    C8,
}

impl Station {
    /// All stations, C1 first.
    pub const ALL: [Station; 8] = [
        Station::C1,
        Station::C2,
        Station::C3,
        Station::C4,
        Station::C5,
        Station::C6,
        Station::C7,
        Station::C8,
    ];

    /// 0 for C1 .. 7 for C8.
    pub fn index(self) -> usize {
        self as usize
    }

    /// The station with index 0..=7, or `None`.
    pub fn from_index(index: usize) -> Option<Self> {
        Self::ALL.get(index).copied()
    }

    /// The mirror (0 = M1 .. 3 = M4) whose outgoing segment this station watches.
    pub fn segment(self) -> usize {
        self.index() / 2
    }
}

impl fmt::Display for Station {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "C{}", self.index() + 1)
    }
}

/// A station name that is not C1..C8.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown camera station {0:?}: use C1..C8")]
pub struct UnknownStation(pub String);

impl FromStr for Station {
    type Err = UnknownStation;

    /// Parses `C1`..`C8` (case-insensitive).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let digits = text
            .strip_prefix(['C', 'c'])
            .ok_or_else(|| UnknownStation(text.to_owned()))?;
        digits
            .parse::<usize>()
            .ok()
            .and_then(|n| n.checked_sub(1))
            .and_then(Self::from_index)
            .ok_or_else(|| UnknownStation(text.to_owned()))
    }
}

/// Where the camera actually sits: a station plus the error of this placement.
///
/// Errors are expressed in the station's frame: x along image right, y along image down,
/// z along the beam; rotations are small rotation vectors about those axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraPose {
    /// The station the camera was sent to.
    pub station: Station,
    /// Position error, mm (x, y, z).
    pub offset_mm: [f64; 3],
    /// Rotation error, rad (about x, y, z).
    pub rotation_rad: [f64; 3],
}

impl CameraPose {
    /// The camera exactly at the station's calibrated pose.
    pub fn nominal(station: Station) -> Self {
        Self {
            station,
            offset_mm: [0.0; 3],
            rotation_rad: [0.0; 3],
        }
    }

    /// The camera placed at `station` with Gaussian position and rotation errors of the
    /// configured standard deviations, drawn from `rng` (seed it for reproducible runs).
    pub fn place<R: Rng + ?Sized>(
        station: Station,
        camera: &RelayCameraParams,
        rng: &mut R,
    ) -> Self {
        let pos = camera.placement_position_std_mm;
        let rot = camera.placement_rotation_std_deg.to_radians();
        Self {
            station,
            offset_mm: std::array::from_fn(|_| pos * standard_normal(rng)),
            rotation_rad: std::array::from_fn(|_| rot * standard_normal(rng)),
        }
    }
}

/// One draw from the standard normal distribution (Box-Muller).
fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let u1 = 1.0 - rng.random::<f64>();
    let u2 = rng.random::<f64>();
    (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn stations_round_trip_and_name_themselves() {
        for (i, s) in Station::ALL.into_iter().enumerate() {
            assert_eq!(Station::from_index(i), Some(s));
            assert_eq!(s.to_string(), format!("C{}", i + 1));
        }
        assert_eq!(Station::from_index(8), None);
        assert_eq!(Station::C4.segment(), 1);
    }

    #[test]
    fn placement_errors_have_the_configured_spread() {
        let camera = RelayCameraParams::default();
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let n = 4000;
        let (mut pos2, mut rot2) = (0.0, 0.0);
        for _ in 0..n {
            let pose = CameraPose::place(Station::C3, &camera, &mut rng);
            pos2 += pose.offset_mm[0].powi(2);
            rot2 += pose.rotation_rad[2].powi(2);
        }
        let pos_std = (pos2 / f64::from(n)).sqrt();
        let rot_std = (rot2 / f64::from(n)).sqrt().to_degrees();
        assert!(
            (pos_std / camera.placement_position_std_mm - 1.0).abs() < 0.06,
            "{pos_std}"
        );
        assert!(
            (rot_std / camera.placement_rotation_std_deg - 1.0).abs() < 0.06,
            "{rot_std}"
        );
    }
}
