//! Seeing what a motor move did: the frame difference shows the feature that moved where it
//! appeared and where it vanished, while stationary beams and artefacts cancel. A sighting
//! is clean when its centroid can be trusted for a fit.

use optalign_optics::Frame;

use super::model::{Vec2, distance};
use crate::imaging::{BeamSpot, changes};

/// Where a moved feature was seen.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sighting {
    pub centre: Vec2,
    /// Whole and alone: fit to it.
    pub clean: bool,
}

/// The moved feature's new and old places.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Seen {
    pub appeared: Option<Sighting>,
    pub vanished: Option<Sighting>,
}

/// An absolute spot this close to a difference blob is the same feature, px.
const SAME_SPOT_PX: f64 = 30.0;

/// The strongest change from `before` to `after` in each direction among blobs `accept`
/// allows. With `absolute`, a sighting is clean only when the plain frame shows the feature
/// as its own unclipped spot (the absolute centroid is then used); without, when the
/// difference blob is unclipped.
pub fn sighting(
    before: &Frame,
    after: &Frame,
    before_spots: &[BeamSpot],
    after_spots: &[BeamSpot],
    absolute: bool,
    accept: impl Fn(Vec2) -> bool,
) -> Seen {
    let moved = changes(before, after);
    let pick = |blobs: &[BeamSpot], spots: &[BeamSpot]| {
        let blob = blobs.iter().find(|b| accept(b.centre))?;
        if !absolute {
            return Some(Sighting {
                centre: blob.centre,
                clean: !blob.clipped,
            });
        }
        let spot = spots
            .iter()
            .find(|s| !s.clipped && distance(s.centre, blob.centre) < SAME_SPOT_PX);
        Some(match spot {
            Some(s) if !blob.clipped => Sighting {
                centre: s.centre,
                clean: true,
            },
            _ => Sighting {
                centre: blob.centre,
                clean: false,
            },
        })
    };
    Seen {
        appeared: pick(&moved.appeared, after_spots),
        vanished: pick(&moved.vanished, before_spots),
    }
}
