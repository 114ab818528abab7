//! A beam's bright core, the light above a share of its peak: its centroid and size. Faint
//! neighbours lie below that level; a saturated core's flat top is symmetric.

use super::tuning::{CORE_PASSES, CORE_WINDOW_RADII};
use super::{Beam, Picture};

/// The centroid of `beam`'s light above `share` of its peak, weighted by the excess, if any.
pub fn core_centre(picture: &Picture, beam: &Beam, share: f64) -> Option<[f64; 2]> {
    let (w, h) = (picture.width(), picture.height());
    let level = (share * beam.peak) as f32;
    let half = CORE_WINDOW_RADII * beam.size().max(1.0);
    let mut centre = beam.centre;
    for _ in 0..CORE_PASSES {
        let (mut s, mut sx, mut sy) = (0.0f64, 0.0f64, 0.0f64);
        for y in pixel_range(centre[1], half, h) {
            let row = &picture.light()[y * w..(y + 1) * w];
            let (rs, rsx) = pixel_range(centre[0], half, w)
                .map(|x| (row[x] - level, x as f32))
                .filter(|&(above, _)| above > 0.0)
                .fold((0f32, 0f32), |(rs, rsx), (a, x)| (rs + a, rsx + a * x));
            s += f64::from(rs);
            sx += f64::from(rsx);
            sy += f64::from(rs) * y as f64;
        }
        if s <= 0.0 {
            return None;
        }
        centre = [sx / s + 0.5, sy / s + 0.5];
    }
    Some(centre)
}

/// The radius, px, of a disc as large as where `beam` near `centre` exceeds `share` of its peak.
pub fn core_radius(
    picture: &Picture,
    centre: [f64; 2],
    beam: &Beam,
    share: f64,
    reach_radii: f64,
) -> f64 {
    let level = (share * beam.peak) as f32;
    let (w, h) = (picture.width(), picture.height());
    let reach = reach_radii * beam.size();
    let bright = pixel_range(centre[1], reach, h)
        .flat_map(|y| pixel_range(centre[0], reach, w).map(move |x| y * w + x))
        .filter(|&i| picture.light()[i] > level || picture.saturated()[i])
        .count();
    (bright as f64 / std::f64::consts::PI).sqrt()
}

/// The pixel indices within `half` of `c` along an image side of `side` pixels.
pub(crate) fn pixel_range(c: f64, half: f64, side: usize) -> std::ops::Range<usize> {
    let lo = (c - half).floor().max(0.0) as usize;
    let hi = ((c + half).ceil().max(0.0) as usize).min(side);
    lo..hi
}
