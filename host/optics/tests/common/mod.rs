//! Image measurements shared by the integration tests.

// Each test binary uses a subset of these helpers.
#![allow(dead_code)]

use optalign_optics::Frame;

/// Intensity-weighted centroid (pixel centres at i + 0.5) of the pixels above `floor`, with
/// `floor` subtracted, and the total weight.
pub fn centroid(frame: &Frame, floor: f64) -> ([f64; 2], f64) {
    let (mut sx, mut sy, mut sw) = (0.0, 0.0, 0.0);
    for y in 0..frame.height() {
        for x in 0..frame.width() {
            let v = f64::from(frame.pixel(x, y)) - floor;
            if v > 0.0 {
                sx += v * (f64::from(x) + 0.5);
                sy += v * (f64::from(y) + 0.5);
                sw += v;
            }
        }
    }
    ([sx / sw, sy / sw], sw)
}

/// Mean gray level of the rectangle `[x0, x1) x [y0, y1)`.
pub fn mean(frame: &Frame, x0: u32, x1: u32, y0: u32, y1: u32) -> f64 {
    let mut sum = 0.0;
    for y in y0..y1 {
        for x in x0..x1 {
            sum += f64::from(frame.pixel(x, y));
        }
    }
    sum / f64::from((x1 - x0) * (y1 - y0))
}

/// Largest absolute pixel difference between two frames over the rectangle.
pub fn max_diff(a: &Frame, b: &Frame, x0: u32, x1: u32, y0: u32, y1: u32) -> u16 {
    let mut worst = 0;
    for y in y0..y1 {
        for x in x0..x1 {
            worst = worst.max(a.pixel(x, y).abs_diff(b.pixel(x, y)));
        }
    }
    worst
}
