//! Which beam an axis moves, told by the frames' difference rather than by brightness:
//! a probe move of the axis, then what appeared and vanished between the frames before
//! and after it. The beams that stayed put are remembered so a scan never follows them.

use crate::imaging::{Beam, Picture, changes, find_beams, nearest};

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
    let appeared = difference
        .appeared
        .iter()
        .max_by(|a, b| a.signal.total_cmp(&b.signal))?;
    let to = *nearest(&seen_after, appeared.centre)?;
    let from = match difference
        .vanished
        .iter()
        .max_by(|a, b| a.signal.total_cmp(&b.signal))
    {
        Some(vanished) => *nearest(&seen_before, vanished.centre)?,
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

    fn probe_of_still() -> Option<Probe> {
        probe(&picture([200.0, 150.0]), &picture([200.0, 150.0]))
    }
}
