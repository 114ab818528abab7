//! What changed between two pictures of one camera: their difference on one background, less the
//! room's light (a plane) and the laser's drift (a gain), searched for beams both ways.

use super::beams::{Beam, find_changed, find_faint_beams};
use super::cells::{CellSums, around, f64_sum};
use super::picture::{Picture, kept, median_f32, robust_spread};
use super::tuning::{
    BACKGROUND_STRIDE, GAIN_MIN_PIXELS, GAIN_NOISES, GAIN_STRIDE, LEVEL_CELL, LEVEL_OUTLIER,
    SIDE_BLOCK, SIDE_NOISES,
};

/// What moved between two pictures.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    /// Where light appeared (a moved beam's new place).
    pub appeared: Vec<Beam>,
    /// Where light vanished (its old place).
    pub vanished: Vec<Beam>,
    /// The later picture's light over the earlier one's, for what stayed (1 without drift).
    pub gain: f64,
}

/// The changes from `before` to `after`; empty when the sizes differ.
pub fn changes(before: &Picture, after: &Picture) -> Changes {
    registered_changes(before, after, [0.0, 0.0])
}

/// The changes when the stationary scene moved by `shift`, px (x right, y down): `before` is
/// resampled onto `after` first; appeared in `after`'s coordinates, vanished in `before`'s.
pub fn registered_changes(before: &Picture, after: &Picture, shift: [f64; 2]) -> Changes {
    changes_found(before, after, shift, None)
}

/// [`registered_changes`] for a beam of about `radius` px, looked for on wider averages too.
pub fn registered_changes_sized(
    before: &Picture,
    after: &Picture,
    shift: [f64; 2],
    radius: f64,
) -> Changes {
    changes_found(before, after, shift, Some(radius))
}

fn changes_found(
    before: &Picture,
    after: &Picture,
    shift: [f64; 2],
    faint: Option<f64>,
) -> Changes {
    if before.width() != after.width() || before.height() != after.height() {
        return Changes::default();
    }
    let (w, h) = (after.width(), after.height());
    let earlier = Shifted::new(before, shift);
    let b = &earlier.light;
    let known = |i: usize| !earlier.unknown[i] && !after.saturated()[i];
    // Fits of a structured background can differ by gray levels: compare on `before`'s.
    let mut stayed = on_earlier_background(before, after, shift);
    let difference = |stayed: &[f32], g: f32| -> Vec<f32> {
        (0..w * h)
            .map(|i| if known(i) { stayed[i] - g * b[i] } else { 0.0 })
            .collect()
    };
    let [level, slope_x, slope_y] = level_plane(&difference(&stayed, 1.0), w, h);
    for (y, row) in stayed.chunks_exact_mut(w).enumerate() {
        let y = y as f64 + 0.5;
        for (x, v) in row.iter_mut().enumerate() {
            *v -= (level + slope_x * (x as f64 + 0.5) + slope_y * y) as f32;
        }
    }
    let gain = steady_gain(&earlier, before.noise(), after, &stayed);
    let difference = difference(&stayed, gain as f32);
    let noise = after.noise().hypot(gain * before.noise());
    let noise_map = after.noise_map().of_difference(before.noise_map(), gain);
    let side = |sign: f32| {
        let light = one_side(&difference, w, h, sign, noise);
        let picture = after.with_difference(light, noise, noise_map.clone());
        match faint {
            Some(radius) => find_faint_beams(&picture, radius),
            None => find_changed(&picture),
        }
    };
    let back = [-shift[0], -shift[1]];
    Changes {
        appeared: side(1.0),
        vanished: side(-1.0).iter().map(|b| b.translated(back)).collect(),
        gain,
    }
}

/// `after`'s light on `before`'s background at `shift`, gray levels (the smooth gap interpolated).
fn on_earlier_background(before: &Picture, after: &Picture, shift: [f64; 2]) -> Vec<f32> {
    let w = after.width();
    let drop = |x: f64, y: f64| {
        before.background_at(x - shift[0], y - shift[1]) - after.background_at(x, y)
    };
    let mut out = Vec::with_capacity(after.light().len());
    for (y, light) in after.light().chunks_exact(w).enumerate() {
        let y = y as f64 + 0.5;
        let mut x0 = 0;
        let mut left = drop(0.5, y);
        while x0 < w {
            let x1 = (x0 + BACKGROUND_STRIDE).min(w - 1);
            let right = drop(x1 as f64 + 0.5, y);
            let span = (x1 - x0).max(1) as f64;
            let end = if x1 == w - 1 { w } else { x1 };
            let lower = |x: usize| (left + (right - left) * (x - x0) as f64 / span) as f32;
            out.extend((x0..end).map(|x| light[x] - lower(x)));
            (x0, left) = (end, right);
        }
    }
    out
}

/// A picture's light resampled at a shift (bilinear); `unknown`: saturated or off the border.
struct Shifted {
    light: Vec<f32>,
    unknown: Vec<bool>,
}

impl Shifted {
    fn new(picture: &Picture, shift: [f64; 2]) -> Self {
        let (w, h) = (picture.width(), picture.height());
        if shift == [0.0, 0.0] {
            return Self {
                light: picture.light().to_vec(),
                unknown: picture.saturated().to_vec(),
            };
        }
        // Pixel x reads `x - whole` (weight `1 - part`) and the one before (weight `part`).
        let taps = |s: f64| {
            let whole = s.floor();
            let part = (s - whole) as f32;
            [(whole as isize, 1.0 - part), (whole as isize + 1, part)]
        };
        let (x_taps, y_taps) = (taps(shift[0]), taps(shift[1]));
        let (light, unknown): (Vec<f32>, Vec<bool>) = (0..w * h)
            .map(|pixel| {
                let (x, y) = (pixel % w, pixel / w);
                let (mut sum, mut unknown) = (0f32, false);
                for (dy, fy) in y_taps {
                    for (dx, fx) in x_taps {
                        let weight = fx * fy;
                        if weight == 0.0 {
                            continue;
                        }
                        let (sx, sy) = (x as isize - dx, y as isize - dy);
                        if !(0..w as isize).contains(&sx) || !(0..h as isize).contains(&sy) {
                            unknown = true;
                            continue;
                        }
                        let i = sy as usize * w + sx as usize;
                        unknown |= picture.saturated()[i];
                        sum += weight * picture.light()[i];
                    }
                }
                (sum, unknown)
            })
            .unzip();
        Self { light, unknown }
    }
}

/// The plane (level, x and y slopes per px) of a difference, moved beams' cells rejected.
fn level_plane(difference: &[f32], w: usize, h: usize) -> [f64; 3] {
    let sums = CellSums::new(difference, w, h, LEVEL_CELL, f64_sum);
    let centre = |i: usize, side: usize| {
        ((i * LEVEL_CELL) as f64 + (((i + 1) * LEVEL_CELL).min(side) as f64)) / 2.0
    };
    let cw = sums.columns;
    let cells: Vec<([f64; 3], f64)> = sums
        .means()
        .enumerate()
        .map(|(c, mean)| ([1.0, centre(c % cw, w), centre(c / cw, h)], mean))
        .collect();
    let mut keep = vec![true; cells.len()];
    let mut plane = [0.0; 3];
    for _ in 0..5 {
        let mut normal = nalgebra::Matrix3::<f64>::zeros();
        let mut rhs = nalgebra::Vector3::<f64>::zeros();
        for (row, level) in kept(&cells, &keep) {
            let row = nalgebra::Vector3::from(*row);
            normal += row * row.transpose();
            rhs += row * *level;
        }
        let Some(inverse) = normal.try_inverse() else {
            return plane;
        };
        plane = (inverse * rhs).into();
        let residual = |(row, level): &([f64; 3], f64)| {
            (level - plane[0] - plane[1] * row[1] - plane[2] * row[2]).abs()
        };
        let spread = robust_spread(kept(&cells, &keep).map(residual));
        let next: Vec<bool> = cells
            .iter()
            .map(|c| residual(c) <= LEVEL_OUTLIER * spread)
            .collect();
        if next == keep || next.iter().filter(|k| **k).count() < 3 {
            break;
        }
        keep = next;
    }
    plane
}

/// The difference times `sign`, zeroed near clear changes of the other sign (not to be summed).
fn one_side(difference: &[f32], w: usize, h: usize, sign: f32, noise: f64) -> Vec<f32> {
    let blocks = CellSums::new(difference, w, h, SIDE_BLOCK, |run: &[f32]| {
        sign * run.iter().sum::<f32>()
    });
    let (bw, bh) = (blocks.columns, blocks.rows);
    let limit = -(SIDE_NOISES * noise / SIDE_BLOCK as f64) as f32;
    let opposite: Vec<bool> = blocks
        .sums
        .iter()
        .zip(&blocks.counts)
        .map(|(s, &n)| s / (n as f32).max(1.0) < limit)
        .collect();
    let masked: Vec<bool> = (0..bw * bh)
        .map(|b| around(b, 1, bw, bh).any(|n| opposite[n]))
        .collect();
    let mut out = Vec::with_capacity(difference.len());
    for (y, row) in difference.chunks_exact(w).enumerate() {
        for (chunk, &zero) in row.chunks(SIDE_BLOCK).zip(&masked[(y / SIDE_BLOCK) * bw..]) {
            out.extend(chunk.iter().map(|v| if zero { 0.0 } else { v * sign }));
        }
    }
    out
}

/// The laser's gain from `before` to `after` (`stayed`): the median ratio of bright pixels, or 1.
fn steady_gain(before: &Shifted, before_noise: f64, after: &Picture, stayed: &[f32]) -> f64 {
    let floor_b = GAIN_NOISES * before_noise as f32;
    let floor_a = GAIN_NOISES * after.noise() as f32;
    let b = &before.light;
    let mut ratios: Vec<f32> = (0..b.len())
        .step_by(GAIN_STRIDE)
        .filter(|&i| {
            b[i] > floor_b && stayed[i] > floor_a && !before.unknown[i] && !after.saturated()[i]
        })
        .map(|i| stayed[i] / b[i])
        .collect();
    if ratios.len() < GAIN_MIN_PIXELS {
        return 1.0;
    }
    f64::from(median_f32(&mut ratios))
}
