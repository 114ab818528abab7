//! Finding one mirror's lost axes from the camera: tell its beam by a probe move (the
//! beam that moved, not the brightest), search for it with relative moves when it is not
//! in view, bring it clear of the image border, measure it at two positions each approached
//! from the same side, and bring the axes back to where they started. Nothing is declared
//! here: the offsets between the axes' counters and their true positions are returned.

use super::locate::{Combined, Offset, Response, Sighting, combine, locate};
use super::walk::{Walker, search_pattern};
use crate::imaging::{Beam, Picture, find_beams, median, strongest};
use crate::lab::calibrate::track::{self, Probe, distance};
use crate::lab::rig::LabRig;

/// Sightings of one mirror further apart than this many standard deviations mean the beam
/// followed was not the mirror's, or the mount slipped.
pub const MAX_SPREAD_SIGMAS: f64 = 5.0;

/// A probe moves the beam by about this many of its sizes ...
const PROBE_SIZES: f64 = 1.5;
/// ... and at least this far, px ...
const MIN_PROBE_PX: f64 = 12.0;
/// ... and at most this share of the image's smaller side.
const MAX_PROBE_SHARE: f64 = 1.0 / 6.0;
/// One search step moves the beam by this share of the image's smaller side: small enough
/// that a beam near the centre is not thrown out of view, large enough to part two beams.
const SEARCH_STEP_SHARE: f64 = 1.0 / 3.0;
/// Moves that bring a beam the border cuts towards the centre, at most.
const MOST_CENTRINGS: usize = 3;

/// How a mirror's beam is measured.
#[derive(Clone, Debug)]
pub enum Reading {
    /// The beam's own position through the response (Michelson).
    Absolute(Response),
    /// The beam's offset from the brightest beam that stays put (the cavity's secondary
    /// from its primary): the response's anchor is that offset at its reference.
    FromStationary(Response),
}

impl Reading {
    fn response(&self) -> &Response {
        match self {
            Self::Absolute(r) | Self::FromStationary(r) => r,
        }
    }
}

/// One mirror to find: its two task axes, which of them (0, 1) are lost, and how its beam
/// is read.
pub struct Mirror {
    pub name: String,
    pub axes: [usize; 2],
    pub lost: Vec<usize>,
    pub reading: Reading,
}

/// Finds the mirror's lost axes: the offsets of their true positions from their counters.
/// The axes end where they started (approached from their approach side). The error says
/// why the mirror could not be found.
pub async fn find(
    rig: &mut LabRig,
    mirror: &Mirror,
    search_rings: i32,
    narrate: &mut dyn FnMut(&str),
) -> anyhow::Result<Combined> {
    let lost_axes: Vec<usize> = mirror.lost.iter().map(|&k| mirror.axes[k]).collect();
    let mut walker = Walker::new(rig, &lost_axes).await?;
    let found = look(rig, mirror, &mut walker, search_rings, narrate).await;
    // Back where it started, found or not.
    walker.home(rig).await?;
    found
}

async fn look(
    rig: &mut LabRig,
    mirror: &Mirror,
    walker: &mut Walker,
    search_rings: i32,
    narrate: &mut dyn FnMut(&str),
) -> anyhow::Result<Combined> {
    let start = Picture::new(&rig.capture().await?);
    let seen = find_beams(&start);
    let frame_side = start.width().min(start.height()) as f64;
    let m = mirror.reading.response().matrix;
    let lengths: Vec<f64> = mirror
        .lost
        .iter()
        .map(|&k| m[0][k].hypot(m[1][k]))
        .collect();
    anyhow::ensure!(
        lengths.iter().all(|&l| l > 0.0 && l.is_finite()),
        "{}: the response calibration says its axes do not move the beam",
        mirror.name
    );
    let typical_size = median(
        seen.iter()
            .map(Beam::size)
            .filter(|r| r.is_finite())
            .collect(),
    )
    .unwrap_or(MIN_PROBE_PX);
    let probe_px = (PROBE_SIZES * typical_size)
        .max(MIN_PROBE_PX)
        .min(MAX_PROBE_SHARE * frame_side);
    let scale = (mirror.lost.len() as f64).sqrt();
    let directions = walker.directions();
    let probe: Vec<i32> = lengths
        .iter()
        .zip(&directions)
        .map(|(l, d)| d * (probe_px / (l * scale)).ceil() as i32)
        .collect();
    let expected = |steps: &[i32]| moved_by(mirror, steps);

    narrate(&format!(
        "{}: probing with {} steps to tell its beam from the others",
        mirror.name,
        describe(&probe)
    ));
    let mut identified = identify(rig, walker, &start, &probe, &expected).await?;
    if identified.is_none() {
        let step: Vec<i32> = lengths
            .iter()
            .map(|l| (SEARCH_STEP_SHARE * frame_side / l).round().max(1.0) as i32)
            .collect();
        narrate(&format!(
            "{}: its beam is not in view; searching with steps of {} over {search_rings} ring(s)",
            mirror.name,
            describe(&step)
        ));
        identified = search(rig, walker, &seen, &step, &probe, &expected, search_rings).await?;
    }
    measure(rig, mirror, walker, identified, narrate).await
}

/// Measures the identified beam where it is and one probe further, each approached from the
/// same side; refuses when it was never identified.
async fn measure(
    rig: &mut LabRig,
    mirror: &Mirror,
    walker: &mut Walker,
    identified: Option<Identified>,
    narrate: &mut dyn FnMut(&str),
) -> anyhow::Result<Combined> {
    let Some((probe_result, mut picture, probe)) = identified else {
        anyhow::bail!(
            "{}: its beam was not found (not in view, and not within the search); bring it into view by hand (`optalign jog`), or widen the search with --search-rings",
            mirror.name
        );
    };
    let probe_px = moved_by(mirror, &probe);
    let stationary = strongest(&probe_result.stationary).copied();
    let mut beam = probe_result.to;
    let mut offsets: Vec<Offset> = Vec::new();
    let mut centrings = 0;
    for station in 0..2 {
        if station == 1 {
            // One probe further on, away from where the beam started (where it may have lain
            // on another), unless that takes it within two of its sizes of the border or of
            // the beam that stays put (their tails would join them); one probe back when the
            // beam is not seen whole there.
            let room = |sign: f64| {
                let q = [
                    beam.centre[0] + sign * probe_px[0],
                    beam.centre[1] + sign * probe_px[1],
                ];
                clearance(&picture, q, stationary.as_ref())
            };
            let preferred = if room(1.0) >= 2.0 * beam.size() || room(1.0) >= room(-1.0) {
                1
            } else {
                -1
            };
            let (mut at, mut seen) = (0, None);
            for sign in [preferred, -preferred] {
                let delta: Vec<i32> = probe.iter().map(|p| (sign - at) * p).collect();
                walker.go(rig, &delta).await?;
                at = sign;
                picture = Picture::new(&rig.capture().await?);
                let predicted = [
                    beam.centre[0] + f64::from(sign) * probe_px[0],
                    beam.centre[1] + f64::from(sign) * probe_px[1],
                ];
                seen = probe_result
                    .track(&find_beams(&picture), predicted)
                    .filter(|b| distance(b.centre, predicted) <= tracking_radius(&beam))
                    .filter(|b| whole(b, &beam))
                    .copied();
                if seen.is_some() {
                    break;
                }
            }
            beam = seen.ok_or_else(|| lost_track(mirror))?;
        }
        while beam.clipped && centrings < MOST_CENTRINGS {
            centrings += 1;
            let towards = toward_centre(mirror, &picture, &beam);
            narrate(&format!(
                "{}: the image border cuts its beam; moving it {} steps towards the centre",
                mirror.name,
                describe(&towards)
            ));
            walker.go(rig, &towards).await?;
            let moved = moved_by(mirror, &towards);
            picture = Picture::new(&rig.capture().await?);
            let predicted = [beam.centre[0] + moved[0], beam.centre[1] + moved[1]];
            beam = *probe_result
                .track(&find_beams(&picture), predicted)
                .filter(|b| distance(b.centre, predicted) <= tracking_radius(&beam))
                .ok_or_else(|| lost_track(mirror))?;
        }
        anyhow::ensure!(
            !beam.clipped,
            "{}: the image border still cuts its beam after {MOST_CENTRINGS} moves towards the centre; bring it into view by hand (`optalign jog`)",
            mirror.name
        );
        let sighting = sight(mirror, &picture, &beam, stationary.as_ref())?;
        let counters = rig.counters().await?;
        let counters = mirror.axes.map(|axis| f64::from(counters[axis]));
        let offset = locate(mirror.reading.response(), &sighting, counters, &mirror.lost)
            .ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: the response calibration cannot tell where its lost axes are (singular)",
                    mirror.name
                )
            })?;
        narrate(&format!(
            "{}: beam at ({:.1}, {:.1}) px ± {:.2} px, counters {:?}: offsets {} steps",
            mirror.name,
            beam.centre[0],
            beam.centre[1],
            beam.uncertainty,
            counters.map(|c| c as i64),
            offset
                .steps
                .iter()
                .map(|s| format!("{s:+.1}"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
        offsets.push(offset);
    }
    let combined = combine(&offsets).ok_or_else(|| lost_track(mirror))?;
    anyhow::ensure!(
        combined.spread <= MAX_SPREAD_SIGMAS,
        "{}: its two sightings disagree by {:.1} standard deviations (more than {MAX_SPREAD_SIGMAS}): the beam followed may not be this mirror's, or the mount slips; nothing can be declared from them",
        mirror.name,
        combined.spread
    );
    Ok(combined)
}

/// The measured position of the beam, as the reading needs it.
fn sight(
    mirror: &Mirror,
    picture: &Picture,
    beam: &Beam,
    stationary: Option<&Beam>,
) -> anyhow::Result<Sighting> {
    match &mirror.reading {
        Reading::Absolute(_) => Ok(Sighting {
            centre_px: beam.centre,
            covariance: beam.covariance,
        }),
        Reading::FromStationary(_) => {
            let reference = stationary.ok_or_else(|| {
                anyhow::anyhow!(
                    "{}: no beam stays put in view to measure its beam from (the primary)",
                    mirror.name
                )
            })?;
            let primary = crate::imaging::nearest(&find_beams(picture), reference.centre)
                .filter(|p| distance(p.centre, reference.centre) <= reference.size().max(3.0))
                .copied()
                .ok_or_else(|| {
                    anyhow::anyhow!(
                        "{}: the primary beam left its place; nothing can be measured from it",
                        mirror.name
                    )
                })?;
            let covariance =
                [0, 1].map(|r| [0, 1].map(|c| beam.covariance[r][c] + primary.covariance[r][c]));
            // Located as the calibration located it: by its bright core.
            let anchor = track::anchor_centre(picture, &primary);
            Ok(Sighting {
                centre_px: [beam.centre[0] - anchor[0], beam.centre[1] - anchor[1]],
                covariance,
            })
        }
    }
}

/// A beam told by a probe: what the probe showed, the picture after it, and the probe's
/// steps (the axes rest there).
type Identified = (Probe, Picture, Vec<i32>);

/// Probes from where the axes are: moves them by `probe` and tells the beam that moved as
/// `expected` says it should; failing that, the same the other way. When neither shows the
/// beam the axes come back to where they were.
async fn identify(
    rig: &mut LabRig,
    walker: &mut Walker,
    before: &Picture,
    probe: &[i32],
    expected: &dyn Fn(&[i32]) -> [f64; 2],
) -> anyhow::Result<Option<Identified>> {
    let reverse: Vec<i32> = probe.iter().map(|p| -p).collect();
    let mut at = vec![0; probe.len()];
    for way in [probe.to_vec(), reverse] {
        let delta: Vec<i32> = way.iter().zip(&at).map(|(w, a)| w - a).collect();
        walker.go(rig, &delta).await?;
        at = way.clone();
        let after = Picture::new(&rig.capture().await?);
        if let Some((found, after)) = checked_probe(before, after, expected(&way)) {
            return Ok(Some((found, after, way)));
        }
    }
    let back: Vec<i32> = at.iter().map(|a| -a).collect();
    walker.go(rig, &back).await?;
    Ok(None)
}

/// The beam that moved between `before` and `after`, when it moved about as `expected`
/// (px; within a quarter of its length and 3 px: a beam joined to another moves less), and
/// the picture after.
fn checked_probe(before: &Picture, after: Picture, expected: [f64; 2]) -> Option<(Probe, Picture)> {
    let probe = track::probe(before, &after)?;
    let moved = [
        probe.to.centre[0] - probe.from.centre[0],
        probe.to.centre[1] - probe.from.centre[1],
    ];
    let miss = distance(moved, expected);
    let length = expected[0].hypot(expected[1]);
    (miss <= 0.25 * length + 3.0).then_some((probe, after))
}

/// Visits the search pattern until a beam that was not in the first picture shows and a
/// probe from there moves it as expected.
async fn search(
    rig: &mut LabRig,
    walker: &mut Walker,
    seen: &[Beam],
    step: &[i32],
    probe: &[i32],
    expected: &dyn Fn(&[i32]) -> [f64; 2],
    rings: i32,
) -> anyhow::Result<Option<Identified>> {
    let mut at = vec![0i32; step.len()];
    for point in search_pattern(step.len(), rings) {
        let target: Vec<i32> = point.iter().zip(step).map(|(g, s)| g * s).collect();
        let delta: Vec<i32> = target.iter().zip(&at).map(|(t, a)| t - a).collect();
        walker.go(rig, &delta).await?;
        at = target;
        let picture = Picture::new(&rig.capture().await?);
        let new = find_beams(&picture).into_iter().any(|beam| {
            seen.iter()
                .all(|old| distance(old.centre, beam.centre) > old.size().max(beam.size()).max(5.0))
        });
        if !new {
            continue;
        }
        if let Some(found) = identify(rig, walker, &picture, probe, expected).await? {
            return Ok(Some(found));
        }
    }
    Ok(None)
}

/// Steps of the lost axes that move `beam` halfway to the image's centre (least squares
/// through the response).
fn toward_centre(mirror: &Mirror, picture: &Picture, beam: &Beam) -> Vec<i32> {
    let centre = [picture.width() as f64 / 2.0, picture.height() as f64 / 2.0];
    let wanted = [
        0.5 * (centre[0] - beam.centre[0]),
        0.5 * (centre[1] - beam.centre[1]),
    ];
    let m = mirror.reading.response().matrix;
    let design = nalgebra::DMatrix::from_fn(2, mirror.lost.len(), |r, c| m[r][mirror.lost[c]]);
    let wanted = nalgebra::DVector::from_column_slice(&wanted);
    design
        .svd(true, true)
        .solve(&wanted, 1e-12)
        .map(|steps| steps.iter().map(|s| s.round() as i32).collect())
        .unwrap_or_else(|_| vec![0; mirror.lost.len()])
}

/// Where the response says `steps` of the lost axes move the beam, px.
fn moved_by(mirror: &Mirror, steps: &[i32]) -> [f64; 2] {
    let m = mirror.reading.response().matrix;
    let mut px = [0.0; 2];
    for (&k, &s) in mirror.lost.iter().zip(steps) {
        px[0] += m[0][k] * f64::from(s);
        px[1] += m[1][k] * f64::from(s);
    }
    px
}

/// How clear a beam at `point` would be: its distance to the image border, or to the edge
/// of the beam that stays put (the cavity's primary) when that is nearer, px.
fn clearance(picture: &Picture, point: [f64; 2], stationary: Option<&Beam>) -> f64 {
    let (w, h) = (picture.width() as f64, picture.height() as f64);
    let border = point[0].min(w - point[0]).min(point[1]).min(h - point[1]);
    match stationary {
        Some(other) => border.min(distance(point, other.centre) - other.size()),
        None => border,
    }
}

/// Whether `beam` is the beam `first` seen alone: one part, and not much larger (joined to
/// another beam, its centre would be pulled).
fn whole(beam: &Beam, first: &Beam) -> bool {
    beam.parts == 1 && beam.size() <= WHOLE_GROWTH * first.size()
}

/// How much larger than at its first sighting a beam may look and still be taken as whole.
const WHOLE_GROWTH: f64 = 1.3;

/// How far from its predicted place the beam may be found: its size, at least 5 px.
fn tracking_radius(beam: &Beam) -> f64 {
    beam.size().max(5.0)
}

fn lost_track(mirror: &Mirror) -> anyhow::Error {
    anyhow::anyhow!(
        "{}: its beam was not where the response calibration put it after a move; check the calibration and the mount",
        mirror.name
    )
}

fn describe(steps: &[i32]) -> String {
    steps
        .iter()
        .map(|s| format!("{s:+}"))
        .collect::<Vec<_>>()
        .join(", ")
}
