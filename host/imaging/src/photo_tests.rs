//! The detector on real photographs (docs/scenarios/photos, the repository's copy): the
//! strongest beam it reports must be the photographed beam, at the centre measured
//! independently, and nothing it reports may be degenerate (a radius of 0 px) or a strip of
//! background glow along the frame's edges.
//!
//! The independent centres were measured once by a short pure-Python script (no code of this
//! project: its own PNG decoding, the background as the median of the frame's border, the
//! beam's peak from 8 x 8 block means): the centroid of the light above a share of the step
//! from background to peak, in a window around the brightest block, recentred six times;
//! once at half the step (300 px window) and once at 15 % of it (500 px window). On a beam
//! that is not symmetric (a flare, a lifted halo, two unequal lobes) the two disagree, and
//! the detector, whose window of 2.5 second-moment radii weighs the wings further down, may
//! lie beyond both: a centre is accepted within 3 px plus twice their disagreement.

use std::path::PathBuf;

use optalign_optics::Frame;

use super::{Beam, Picture, find_beams};

/// A photograph and its beam's centre measured independently at half (`half_max`) and at
/// 15 % (`low`) of its peak above the background, px.
struct Photo {
    file: &'static str,
    half_max: [f64; 2],
    low: [f64; 2],
}

impl Photo {
    /// How far the detector's centre may lie from `low`, px.
    fn tolerance_px(&self) -> f64 {
        3.0 + 2.0 * distance(self.half_max, self.low)
    }
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

const PHOTOS: [Photo; 9] = [
    Photo {
        file: "TEM00_300mm.png",
        half_max: [544.96, 118.60],
        low: [542.85, 120.74],
    },
    Photo {
        file: "TEM01_300mm.png",
        half_max: [555.10, 616.83],
        low: [552.74, 615.83],
    },
    Photo {
        file: "sb_259mm_10.png",
        half_max: [649.27, 464.73],
        low: [649.98, 464.63],
    },
    Photo {
        file: "k-500mm.png",
        half_max: [723.69, 470.16],
        low: [724.40, 470.16],
    },
    Photo {
        file: "astigmatic_beam.png",
        half_max: [746.62, 489.34],
        low: [745.85, 489.85],
    },
    Photo {
        file: "t-414mm.png",
        half_max: [477.69, 384.07],
        low: [479.94, 386.86],
    },
    Photo {
        file: "TEM01_100mm.png",
        half_max: [727.22, 623.85],
        low: [727.62, 626.35],
    },
    Photo {
        file: "TEM02_200mm.png",
        half_max: [631.13, 341.22],
        low: [631.93, 341.14],
    },
    Photo {
        file: "k-300mm.png",
        half_max: [567.44, 531.75],
        low: [569.84, 531.62],
    },
];

fn beams_in(file: &str) -> Vec<Beam> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../docs/scenarios/photos")
        .join(file);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let frame = Frame::decode(&bytes, None).unwrap();
    find_beams(&Picture::new(&frame))
}

#[test]
fn the_strongest_beam_is_the_photographed_one_and_none_is_degenerate() {
    for photo in &PHOTOS {
        let beams = beams_in(photo.file);
        let first = beams
            .first()
            .unwrap_or_else(|| panic!("{}: no beam found", photo.file));
        let off = distance(first.centre, photo.low);
        assert!(
            off <= photo.tolerance_px(),
            "{}: strongest beam at {:.2?}, {off:.2} px from the independent centre {:?}; all: {:#?}",
            photo.file,
            first.centre,
            photo.low,
            beams
        );
        // The covariance is a covariance, and small next to the tolerance on a clear beam.
        let [[xx, xy], [yx, yy]] = first.covariance;
        assert!(
            xx > 0.0 && yy > 0.0 && xy == yx && xy * xy < xx * yy,
            "{}",
            photo.file
        );
        assert!(first.uncertainty < photo.tolerance_px(), "{}", photo.file);
        // No beam with a radius of 0 px, no strip of background glow along an edge.
        for beam in &beams {
            assert!(
                beam.radii[1] >= 1.0 && beam.radii[0] < 8.0 * beam.radii[1],
                "{}: a beam at {:.1?} with radii {:.1?}",
                photo.file,
                beam.centre,
                beam.radii
            );
        }
    }
}
