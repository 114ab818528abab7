//! Which beam an axis moves, told by the frames' difference rather than by brightness:
//! a probe move of the axis, then what appeared and vanished between the frames before
//! and after it. The beams that stayed put are remembered so a scan never follows them.

use crate::imaging::{Beam, Picture, changes, core_centre, find_beams, nearest};

/// A beam closer than this to where it was counts as not moved, px.
const STILL_PX: f64 = 2.0;

/// A border-cut beam's Gaussian fit is used when it departs from the pixels by at most
/// this share of its peak (one clean spot; merged spots or fringes depart more).
const MAX_FIT_MISFIT: f64 = 0.15;

/// The outcome of a probe move.
#[derive(Clone, Debug)]
pub struct Probe {
    /// The moved beam before the probe.
    pub from: Beam,
    /// The moved beam after it.
    pub to: Beam,
    /// Beams that did not move.
    pub stationary: Vec<Beam>,
}

/// The beam that moved between `before` and `after`, or `None` when nothing moved (or the
/// moved beam left the view).
pub fn probe(before: &Picture, after: &Picture) -> Option<Probe> {
    let seen_before = find_beams(before);
    let seen_after = find_beams(after);
    let difference = changes(before, after);
    // The strongest change that is not the residue of a beam that stayed (a bright beam's
    // flicker or a pixel of jitter leaves more difference than a dim beam that moved).
    let moved = |changed: &[Beam], seen: &[Beam], other: &[Beam]| -> Option<Beam> {
        let mut changed = changed.to_vec();
        changed.sort_by(|a, b| b.signal.total_cmp(&a.signal));
        changed
            .iter()
            .filter_map(|c| nearest(seen, c.centre))
            .find(|beam| !stayed(beam, other))
            .copied()
    };
    let to = moved(&difference.appeared, &seen_after, &seen_before)?;
    let from = match moved(&difference.vanished, &seen_before, &seen_after) {
        Some(vanished) => vanished,
        None => *nearest(&seen_before, to.centre)?,
    };
    if distance(from.centre, to.centre) <= STILL_PX {
        return None;
    }
    let stationary = seen_before
        .iter()
        .filter(|b| distance(b.centre, from.centre) > STILL_PX)
        .filter(|b| {
            nearest(&seen_after, b.centre).is_some_and(|a| distance(a.centre, b.centre) <= STILL_PX)
        })
        .copied()
        .collect();
    Some(Probe {
        from,
        to,
        stationary,
    })
}

/// Whether `beam` is also in `other` at the same place.
fn stayed(beam: &Beam, other: &[Beam]) -> bool {
    nearest(other, beam.centre).is_some_and(|o| distance(o.centre, beam.centre) <= STILL_PX)
}

impl Probe {
    /// The beam in `beams` nearest `expected` that is not one of the beams that stayed put
    /// (nor overlapping one: a beam within a stationary beam's radius of it is skipped,
    /// its centre would be pulled by the other's light).
    pub fn track<'a>(&self, beams: &'a [Beam], expected: [f64; 2]) -> Option<&'a Beam> {
        let moving: Vec<Beam> = beams
            .iter()
            .filter(|b| {
                self.stationary
                    .iter()
                    .all(|s| distance(b.centre, s.centre) > s.size().max(STILL_PX))
            })
            .copied()
            .collect();
        let found = nearest(&moving, expected)?;
        beams.iter().find(|b| b.centre == found.centre)
    }
}

/// Where a beam's centre is measured: its centroid, or for a beam the border cuts (whose
/// centroid is pulled inwards) its Gaussian fit's centre when that fits; `None` when
/// neither can be trusted.
pub fn measured_centre(beam: &Beam) -> Option<[f64; 2]> {
    if !beam.clipped {
        return Some(beam.centre);
    }
    beam.fit
        .filter(|fit| fit.misfit <= MAX_FIT_MISFIT)
        .map(|fit| fit.centre)
}

/// Share of its peak above which a beam that stays put is located: its bright core, which
/// faint light nearby (another beam passing its halo) does not pull.
const CORE_SHARE: f64 = 0.5;

/// Where a beam that stays put (the cavity's primary) is, to measure another from it: the
/// centre of its bright core, else its centroid.
pub fn anchor_centre(picture: &Picture, beam: &Beam) -> [f64; 2] {
    core_centre(picture, beam, CORE_SHARE).unwrap_or(beam.centre)
}

pub fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::synthetic::Scene;

    /// A brighter beam that stays put and a dimmer one at `moving`.
    fn picture(moving: [f64; 2]) -> Picture {
        Picture::new(
            &Scene::new(320, 240)
                .background(10.0, [0.0, 0.0])
                .gaussian([80.0, 80.0], 14.0, 200.0)
                .gaussian(moving, 12.0, 120.0)
                .noise(2.0, 7)
                .frame(),
        )
    }

    #[test]
    fn the_moved_beam_is_found_by_the_difference_not_by_brightness() {
        let probe = probe(&picture([200.0, 150.0]), &picture([230.0, 140.0])).unwrap();
        assert!(
            distance(probe.from.centre, [200.0, 150.0]) < 1.0,
            "{probe:?}"
        );
        assert!(distance(probe.to.centre, [230.0, 140.0]) < 1.0, "{probe:?}");
        assert_eq!(probe.stationary.len(), 1);
        assert!(distance(probe.stationary[0].centre, [80.0, 80.0]) < 1.0);
        // Tracking never follows the bright beam that stayed, even when it is nearer.
        let later = find_beams(&picture([250.0, 120.0]));
        let tracked = probe.track(&later, [90.0, 85.0]).unwrap();
        assert!(distance(tracked.centre, [250.0, 120.0]) < 1.0);
        // Nothing moved: no probe.
        assert!(probe_of_still().is_none());
    }

    /// The bright beam of `picture` shifted by a pixel and a tenth brighter: the residue
    /// a laser's jitter and flicker leave in the difference.
    fn jittered(moving: [f64; 2]) -> Picture {
        Picture::new(
            &Scene::new(320, 240)
                .background(10.0, [0.0, 0.0])
                .gaussian([81.0, 80.0], 14.0, 220.0)
                .gaussian(moving, 12.0, 30.0)
                .noise(2.0, 8)
                .frame(),
        )
    }

    #[test]
    fn the_residue_of_a_bright_beam_that_stayed_is_not_taken_for_the_moved_beam() {
        let before = Picture::new(
            &Scene::new(320, 240)
                .background(10.0, [0.0, 0.0])
                .gaussian([80.0, 80.0], 14.0, 200.0)
                .gaussian([200.0, 150.0], 12.0, 30.0)
                .noise(2.0, 7)
                .frame(),
        );
        let probe = probe(&before, &jittered([230.0, 140.0])).unwrap();
        assert!(distance(probe.to.centre, [230.0, 140.0]) < 1.0, "{probe:?}");
        assert!(
            distance(probe.from.centre, [200.0, 150.0]) < 1.0,
            "{probe:?}"
        );
    }

    fn probe_of_still() -> Option<Probe> {
        probe(&picture([200.0, 150.0]), &picture([200.0, 150.0]))
    }
}
