//! How far the stationary scene around a bright beam moved: its core's move in whole pixels, if
//! that improves agreement; under half a pixel (a faint spot tugging the core's edge) is none.

use super::core::{core_centre, pixel_range};
use super::tuning::{SHIFT_STRIDE, SHIFT_WINDOW_RADII};
use super::{Beam, Picture};

/// How far the scene around `beam`'s core (above `share` of its peak) moved, whole px; else zero.
pub fn scene_shift(before: &Picture, after: &Picture, beam: &Beam, share: f64) -> [f64; 2] {
    let still = [0.0, 0.0];
    let Some(from) = core_centre(before, beam, share) else {
        return still;
    };
    let moved_beam = Beam {
        centre: from,
        ..*beam
    };
    let Some(to) = core_centre(after, &moved_beam, share) else {
        return still;
    };
    let shift = [(to[0] - from[0]).round(), (to[1] - from[1]).round()];
    if shift == still {
        return still;
    }
    let window = SHIFT_WINDOW_RADII * beam.size().max(1.0);
    match misfits(before, after, from, window, [shift, still]) {
        Some([moved, stayed]) if moved < stayed => shift,
        _ => still,
    }
}

/// For each shift, the sum of squares left of `after` around `centre` (`half` px per axis) once
/// `before`, shifted and scaled by its best gain, is taken off; `None` when nothing is compared.
fn misfits(
    before: &Picture,
    after: &Picture,
    centre: [f64; 2],
    half: f64,
    shifts: [[f64; 2]; 2],
) -> Option<[f64; 2]> {
    let (w, h) = (after.width(), after.height());
    let span = |c: f64, side: usize| pixel_range(c, half, side).step_by(SHIFT_STRIDE);
    let mut sums = [[0.0f64; 3]; 2];
    for y in span(centre[1], h) {
        for x in span(centre[0], w) {
            let i = y * w + x;
            if after.saturated()[i] {
                continue;
            }
            let point = |s: [f64; 2]| [x as f64 + 0.5 - s[0], y as f64 + 0.5 - s[1]];
            let [Some(b0), Some(b1)] = shifts.map(|s| sample(before, point(s))) else {
                continue;
            };
            let a = f64::from(after.light()[i]);
            for (sum, b) in sums.iter_mut().zip([b0, b1]) {
                sum[0] += a * a;
                sum[1] += a * b;
                sum[2] += b * b;
            }
        }
    }
    let left = |[aa, ab, bb]: [f64; 3]| (bb > 0.0).then(|| aa - ab * ab / bb);
    Some([left(sums[0])?, left(sums[1])?])
}

/// The bilinear light at `point` (pixel centres at `i + 0.5`); `None` off the picture or saturated.
fn sample(picture: &Picture, point: [f64; 2]) -> Option<f64> {
    let (w, h) = (picture.width(), picture.height());
    let (x, y) = (point[0] - 0.5, point[1] - 0.5);
    if x < 0.0 || y < 0.0 || x >= (w - 1) as f64 || y >= (h - 1) as f64 {
        return None;
    }
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (fx, fy) = (x - x0 as f64, y - y0 as f64);
    let i = y0 * w + x0;
    let corners = [i, i + 1, i + w, i + w + 1];
    if corners.iter().any(|&c| picture.saturated()[c]) {
        return None;
    }
    let at = |c: usize| f64::from(picture.light()[c]);
    let top = at(corners[0]) * (1.0 - fx) + at(corners[1]) * fx;
    let bottom = at(corners[2]) * (1.0 - fx) + at(corners[3]) * fx;
    Some(top * (1.0 - fy) + bottom * fy)
}
