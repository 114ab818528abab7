//! Seeing what a motor move did: the frame difference shows the feature that moved where it
//! appeared and where it vanished, while stationary beams and artefacts cancel. A sighting
//! is clean when its centroid can be trusted for a fit.

use optalign_optics::Frame;

use super::model::{SAME_STEP, Tracker, Vec2, distance};
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

/// An absolute spot this close to a difference blob is the same feature, px, at least; a
/// large spot may be farther (for short moves the difference blobs are pushed apart).
const SAME_SPOT_PX: f64 = 30.0;

/// A spot fit worse than this (RMS share of the peak) is two spots merged or fringes.
const MAX_MISFIT: f64 = 0.06;

/// A fitted centre is trusted up to this many fitted radii outside the image (farther out,
/// and in a corner, too little of the spot shows).
const MAX_EXTRAPOLATION: f64 = 0.4;

/// Where a moved feature shows, the other frame may hold at most this share of its light.
const FRESH_SHARE: f64 = 0.35;

/// Half the side of the window [`level`] averages, px.
const LEVEL_HALF_WINDOW: i64 = 4;

/// A companion's difference blob lies within this distance of where it was predicted, px.
const COMPANION_PX: f64 = 250.0;

/// Which difference blobs may be the moved feature.
#[derive(Default)]
pub struct BlobFilter<'a> {
    /// Only blobs whose centre this accepts, when given.
    pub accept: Option<&'a dyn Fn(Vec2) -> bool>,
    /// Another feature that moved in the same action from `.0` to about `.1`: the vanished
    /// blob nearest `.0` and the appeared blob nearest `.1` are its, not the feature's.
    pub companion: Option<(Vec2, Vec2)>,
}

impl BlobFilter<'_> {
    /// The strongest blob that may be the feature; `companion_at` is where the companion's
    /// blob of this kind would be.
    fn pick<'b>(&self, blobs: &'b [BeamSpot], companion_at: Option<Vec2>) -> Option<&'b BeamSpot> {
        let companion = companion_at.and_then(|at| {
            blobs
                .iter()
                .map(|b| (b, distance(b.centre, at)))
                .filter(|(_, d)| *d < COMPANION_PX)
                .min_by(|a, b| a.1.total_cmp(&b.1))
                .map(|(b, _)| b.centre)
        });
        blobs.iter().find(|b| {
            self.accept.is_none_or(|accept| accept(b.centre)) && Some(b.centre) != companion
        })
    }
}

/// The strongest change from `before` to `after` in each direction among the blobs `filter`
/// allows. With `absolute`, a sighting is clean only when the plain frame shows the feature
/// as a spot of its own whose Gaussian fit can be trusted (its fitted centre is used, so a
/// spot cut by the border still counts); without, when the difference blob is unclipped.
pub fn sighting(
    before: &Frame,
    after: &Frame,
    before_spots: &[BeamSpot],
    after_spots: &[BeamSpot],
    absolute: bool,
    filter: &BlobFilter,
) -> Seen {
    let moved = changes(before, after);
    let pick = |blobs: &[BeamSpot],
                companion_at: Option<Vec2>,
                spots: &[BeamSpot],
                frame: &Frame,
                other: &Frame| {
        let blob = filter.pick(blobs, companion_at)?;
        if !absolute {
            return Some(Sighting {
                centre: blob.centre,
                clean: !blob.clipped,
            });
        }
        let spot = spots
            .iter()
            .filter(|s| distance(s.centre, blob.centre) < SAME_SPOT_PX.max(0.5 * s.radius))
            .min_by(|a, b| {
                distance(a.centre, blob.centre).total_cmp(&distance(b.centre, blob.centre))
            });
        // The feature must be new where it shows: light that was there in the other frame
        // too (a beam it overlapped, whose fringes changed) is not the moved feature.
        let fresh = |s: &&BeamSpot| level(other, s.centre) < FRESH_SHARE * level(frame, s.centre);
        Some(
            match spot.filter(fresh).and_then(|s| trusted_centre(s, frame)) {
                Some(centre) => Sighting {
                    centre,
                    clean: true,
                },
                None => Sighting {
                    centre: spot.map_or(blob.centre, |s| s.centre),
                    clean: false,
                },
            },
        )
    };
    Seen {
        appeared: pick(
            &moved.appeared,
            filter.companion.map(|c| c.1),
            after_spots,
            after,
            before,
        ),
        vanished: pick(
            &moved.vanished,
            filter.companion.map(|c| c.0),
            before_spots,
            before,
            after,
        ),
    }
}

/// The mean gray level in a small window around `point` (clamped to the image).
fn level(frame: &Frame, point: Vec2) -> f64 {
    let (w, h) = (i64::from(frame.width()), i64::from(frame.height()));
    let (cx, cy) = (point[0].floor() as i64, point[1].floor() as i64);
    let (mut sum, mut n) = (0u64, 0u64);
    for y in (cy - LEVEL_HALF_WINDOW).max(0)..=(cy + LEVEL_HALF_WINDOW).min(h - 1) {
        for x in (cx - LEVEL_HALF_WINDOW).max(0)..=(cx + LEVEL_HALF_WINDOW).min(w - 1) {
            sum += u64::from(frame.pixels()[(y * w + x) as usize]);
            n += 1;
        }
    }
    if n == 0 { 0.0 } else { sum as f64 / n as f64 }
}

/// The centre of a spot when its Gaussian fit is good: one spot, not merged with another,
/// and not extrapolated far beyond the image.
pub fn trusted_centre(spot: &BeamSpot, frame: &Frame) -> Option<Vec2> {
    let fit = spot.fit.filter(|f| f.misfit < MAX_MISFIT)?;
    let outside = |c: f64, side: u32| (-c).max(c - f64::from(side)).max(0.0);
    let beyond =
        outside(fit.centre[0], frame.width()).hypot(outside(fit.centre[1], frame.height()));
    (beyond < MAX_EXTRAPOLATION * fit.radius).then_some(fit.centre)
}

impl Tracker {
    /// Files what a move from command `old` to `new` showed: the feature where it appeared
    /// (or missing), and where it vanished when nothing was recorded at `old` yet (the
    /// start). A vanished blob at a command already looked at is not trusted: when the
    /// feature had overlapped another one, their interference leaves a blob there too.
    pub fn record_move(&mut self, old: Vec2, new: Vec2, seen: Seen) {
        let untried = !self.tried_within(old, SAME_STEP);
        self.record(new, seen.appeared);
        if let (true, Some(s)) = (untried, seen.vanished) {
            self.record(old, Some(s));
        }
    }

    /// Files one sighting (or its absence) at `command`.
    pub fn record(&mut self, command: Vec2, seen: Option<Sighting>) {
        match seen {
            Some(Sighting {
                centre,
                clean: true,
            }) => self.add_clean(command, centre),
            Some(Sighting {
                centre,
                clean: false,
            }) => self.add_partial(command, centre),
            None => self.add_missing(command),
        }
    }
}
