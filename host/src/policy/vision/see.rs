//! What the agent sees in a frame ([`View`]) and what a move changed ([`motion`]: the beam that
//! moved, found in the frames' difference, where all that stayed cancels).

use optalign_optics::Frame;

use super::model::{Vec2, distance};
use super::tuning::{
    ALIKE_LIGHT, ALIKE_SIZE, APART_RADII, MERGED_LIGHT, MERGED_SIZE, SEE_RESIDUE_SHARE,
    STEADY_UNCERTAINTIES,
};
use crate::imaging::{Beam, Changes, Picture, changes, find_beams, nearest, strongest};

/// One frame, measured.
pub struct View {
    pub picture: Picture,
    pub beams: Vec<Beam>,
}

impl View {
    pub fn new(frame: &Frame) -> Self {
        Self::of(Picture::new(frame))
    }

    /// A picture already made ready (a frame with stationary light taken off).
    pub fn of(picture: Picture) -> Self {
        let beams = find_beams(&picture);
        Self { picture, beams }
    }

    /// The image size, px.
    pub fn size(&self) -> Vec2 {
        [self.picture.width() as f64, self.picture.height() as f64]
    }

    pub fn shorter_side(&self) -> f64 {
        let [w, h] = self.size();
        w.min(h)
    }

    pub fn centre(&self) -> Vec2 {
        self.size().map(|s| s / 2.0)
    }
}

/// One place of the moved beam.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Seen {
    /// The beam there: the view's own detection, or only the change when that had none.
    pub beam: Beam,
    /// Measured on the view's own beam, which holds the moved beam alone.
    pub whole: bool,
    /// The change in the frames' difference: the moved beam alone, whatever it merged with.
    pub change: Beam,
}

/// How the beam that moved shows in two views.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Motion {
    /// Where it was (`None`: not in the earlier view).
    pub from: Option<Seen>,
    /// Where it is now (`None`: not in the later view).
    pub to: Option<Seen>,
}

/// Whether two detections can be the same feature (alike in size and light).
pub fn alike(a: &Beam, b: &Beam) -> bool {
    let size = a.size().max(1.0) / b.size().max(1.0);
    let light = a.signal.max(1.0) / b.signal.max(1.0);
    (ALIKE_SIZE[0]..ALIKE_SIZE[1]).contains(&size)
        && (ALIKE_LIGHT[0]..ALIKE_LIGHT[1]).contains(&light)
}

/// Whether change `blob` lies inside one of `features` with under `share` of its light (flicker).
pub fn residue<'a>(blob: &Beam, features: impl IntoIterator<Item = &'a Beam>, share: f64) -> bool {
    features
        .into_iter()
        .any(|f| distance(blob.centre, f.centre) < f.size() && blob.signal < share * f.signal)
}

/// The beams of `before` and `after` paired as stationary features (index pairs), nearest first.
pub fn stationary_pairs(before: &[Beam], after: &[Beam], steady: f64) -> Vec<(usize, usize)> {
    let mut candidates: Vec<(f64, usize, usize)> = Vec::new();
    for (i, a) in before.iter().enumerate() {
        for (j, b) in after.iter().enumerate() {
            let d = distance(a.centre, b.centre);
            let allowance = steady
                .max(STEADY_UNCERTAINTIES * a.uncertainty.hypot(b.uncertainty))
                .max(1.0);
            if d <= allowance && alike(a, b) {
                candidates.push((d, i, j));
            }
        }
    }
    candidates.sort_by(|x, y| x.0.total_cmp(&y.0));
    let mut pairs: Vec<(usize, usize)> = Vec::new();
    for (_, i, j) in candidates {
        if !pairs.iter().any(|p| p.0 == i || p.1 == j) {
            pairs.push((i, j));
        }
    }
    pairs
}

/// The beam that moved from `before` to `after`: the change nearest `expected` (else the
/// strongest) other than `avoid`'s, measured on the views' beams that did not stay put.
pub fn motion(
    before: &View,
    after: &View,
    steady: f64,
    expected: Option<Vec2>,
    avoid: Option<(Vec2, Vec2)>,
) -> Motion {
    let moved = changes(&before.picture, &after.picture);
    motion_in(&moved, before, after, steady, expected, avoid)
}

/// [`motion`] read from the views' difference `moved`, for a caller that looks at it too.
pub fn motion_in(
    moved: &Changes,
    before: &View,
    after: &View,
    steady: f64,
    expected: Option<Vec2>,
    avoid: Option<(Vec2, Vec2)>,
) -> Motion {
    let pairs = stationary_pairs(&before.beams, &after.beams, steady);
    let (stayed_before, stayed_after): (Vec<usize>, Vec<usize>) = pairs.into_iter().unzip();
    let candidates = |blobs: &[Beam], view: &View, stayed: &[usize], avoid: Option<Vec2>| {
        let mut real: Vec<Beam> = blobs
            .iter()
            .filter(|b| !residue(b, stayed.iter().map(|&i| &view.beams[i]), SEE_RESIDUE_SHARE))
            .copied()
            .collect();
        let nearest_avoided = avoid.and_then(|p| {
            nearest(&real, p)
                .filter(|b| distance(b.centre, p) < APART_RADII * b.size())
                .map(|b| b.centre)
        });
        real.retain(|b| Some(b.centre) != nearest_avoided);
        real
    };
    let appeared = candidates(&moved.appeared, after, &stayed_after, avoid.map(|a| a.1));
    let vanished = candidates(&moved.vanished, before, &stayed_before, avoid.map(|a| a.0));
    let to = expected
        .map_or_else(|| strongest(&appeared), |point| nearest(&appeared, point))
        .copied();
    let from = match to {
        Some(t) => vanished
            .iter()
            .filter(|b| (ALIKE_LIGHT[0]..ALIKE_LIGHT[1]).contains(&(b.signal / t.signal.max(1.0))))
            .max_by(|a, b| a.signal.total_cmp(&b.signal))
            .or_else(|| strongest(&vanished))
            .copied(),
        None => strongest(&vanished).copied(),
    };
    // Apart, each change is the whole beam: a detection with much more light holds another too.
    let apart = from
        .zip(to)
        .is_none_or(|(f, t)| distance(f.centre, t.centre) > APART_RADII * f.size().max(t.size()));
    // A change's place: the nearest detection covering it that did not stay put, else itself.
    let place = |blob: Beam, beams: &[Beam], stayed: &[usize]| {
        let covering: Vec<Beam> = beams
            .iter()
            .enumerate()
            .filter(|&(i, b)| {
                !stayed.contains(&i) && distance(b.centre, blob.centre) < blob.size() + b.size()
            })
            .map(|(_, b)| *b)
            .collect();
        let own = nearest(&covering, blob.centre);
        Seen {
            beam: *own.unwrap_or(&blob),
            whole: own.is_some_and(|b| !(apart && b.signal > MERGED_LIGHT * blob.signal)),
            change: blob,
        }
    };
    let mut from = from.map(|b| place(b, &before.beams, &stayed_before));
    let mut to = to.map(|b| place(b, &after.beams, &stayed_after));
    if let (Some(f), Some(t)) = (&mut from, &mut to)
        && f.whole
        && t.whole
        && !f.beam.clipped
        && !t.beam.clipped
    {
        if f.beam.size() > MERGED_SIZE * t.beam.size() {
            f.whole = false;
        } else if t.beam.size() > MERGED_SIZE * f.beam.size() {
            t.whole = false;
        }
    }
    Motion { from, to }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn beam(centre: Vec2, size: f64, signal: f64) -> Beam {
        Beam {
            centre,
            uncertainty: 0.2,
            covariance: [[0.02, 0.0], [0.0, 0.02]],
            radii: [size, size],
            angle_deg: 0.0,
            signal,
            peak: 100.0,
            saturated: false,
            clipped: false,
            edge_level: 0.0,
            localised: true,
            parts: 1,
            fit: None,
        }
    }

    #[test]
    fn stationary_features_pair_up_within_the_jitter_allowance() {
        let stray = beam([100.0, 100.0], 30.0, 5e4);
        let other = beam([600.0, 300.0], 60.0, 3e5);
        let was = beam([300.0, 200.0], 55.0, 2.5e5);
        let now = beam([340.0, 260.0], 55.0, 2.6e5);
        let jittered =
            |b: &Beam, d: f64| beam([b.centre[0] + d, b.centre[1] - d], b.size(), b.signal);
        let before = [stray, other, was];
        let after = [jittered(&other, 1.5), now, jittered(&stray, -1.0)];
        let pairs = stationary_pairs(&before, &after, 4.0);
        assert_eq!(pairs, vec![(0, 2), (1, 0)]);
    }

    #[test]
    fn the_moved_beam_is_found_in_the_difference_also_when_it_was_merged() {
        use crate::imaging::synthetic::Scene;
        let frame = |first: [f64; 2], seed: u64| {
            Scene::new(640, 480)
                .background(8.0, [0.0, 0.0])
                .gaussian([470.0, 260.0], 45.0, 140.0)
                .gaussian([90.0, 400.0], 25.0, 90.0)
                .gaussian(first, 40.0, 150.0)
                .noise(2.5, seed)
                .frame()
        };
        // The first beam starts merged with the other one and moves clear of it.
        let before = View::new(&frame([420.0, 230.0], 1));
        let after = View::new(&frame([250.0, 200.0], 2));
        let moved = motion(&before, &after, 3.0, None, None);
        let to = moved.to.expect("it shows where it went");
        assert!(to.whole, "{to:?}");
        assert!(distance(to.beam.centre, [250.0, 200.0]) < 0.5, "{to:?}");
        let from = moved.from.expect("and where it was");
        assert!(!from.whole, "it was merged with the other beam: {from:?}");
        // A short move: both places overlap, the detections are still measured whole.
        let nearby = View::new(&frame([290.0, 215.0], 3));
        let short = motion(&after, &nearby, 3.0, None, None);
        let [from, to] = [short.from.unwrap(), short.to.unwrap()];
        assert!(from.whole && to.whole, "{short:?}");
        assert!(
            distance(from.beam.centre, [250.0, 200.0]) < 0.5,
            "{short:?}"
        );
        assert!(distance(to.beam.centre, [290.0, 215.0]) < 0.5, "{short:?}");
        // Nothing moved.
        let again = View::new(&frame([290.0, 215.0], 4));
        assert_eq!(motion(&nearby, &again, 3.0, None, None), Motion::default());
    }
}
