//! Finding beams in an image: a robust background and noise estimate, a threshold,
//! connected bright regions, and for each an intensity-weighted sub-pixel centroid, whether
//! it is a localised spot or a diffuse speckle cloud, and whether the image border cuts it.
//! The same segmentation runs on the signed difference of two frames, where everything
//! stationary cancels and only what moved remains.

use optalign_optics::Frame;

use super::gaussian::{GaussianFit, GaussianFitter};

/// A bright region of an image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamSpot {
    /// Intensity-weighted centroid, px (x right, y down).
    pub centre: [f64; 2],
    /// Summed intensity above the background.
    pub signal: f64,
    /// A compact spot rather than a scattered speckle cloud.
    pub localised: bool,
    /// The region reaches the image border, so the centroid is pulled inwards.
    pub clipped: bool,
    /// Intensity-weighted RMS radius, px.
    pub radius: f64,
    /// A round Gaussian fitted to the unsaturated pixels, when they fall off like a spot.
    /// For a clipped spot its centre is the true one (the centroid is pulled inwards).
    pub fit: Option<GaussianFit>,
}

/// Pixels per side of the blocks the image is reduced to before segmentation.
const BLOCK: usize = 4;

/// Regions with less than this share of the strongest region's light are dropped.
const MIN_SHARE: f64 = 0.02;

/// Regions with less summed light above the background than this are noise.
const MIN_SIGNAL: f64 = 2000.0;

/// Mean neighbour difference over mean signal, above which a region is speckle.
const MAX_SPOT_ROUGHNESS: f64 = 0.15;

/// This many pixels at a region's brightest level make a saturated plateau.
const SATURATION_PLATEAU: usize = 4;

/// A pixel is bright when it exceeds the background by this many read-noise deviations.
const THRESHOLD_NOISES: f64 = 6.0;

/// The spot fit uses pixels brighter than this share of the region's peak and this many
/// read-noise deviations: the faint rim carries mostly noise.
const FIT_FLOOR_SHARE: f64 = 0.08;
const FIT_FLOOR_NOISES: f64 = 3.0;

/// A fitted radius beyond this multiple of the region's RMS radius is a flat clump of
/// noise, not a spot (a Gaussian's 1/e² radius is about 1.4 times its RMS radius).
const MAX_FIT_RADIUS_SHARE: f64 = 3.0;

/// Beams in `frame`, brightest first. Regions smaller than a few blocks are noise.
pub fn find_beams(frame: &Frame) -> Vec<BeamSpot> {
    let values: Vec<f32> = frame.pixels().iter().map(|&p| f32::from(p)).collect();
    let (background, noise) = background_and_noise(&values);
    segment(
        &values,
        frame.width() as usize,
        frame.height() as usize,
        background,
        noise,
    )
}

/// What moved between two frames of the same size: regions that became brighter
/// (`appeared`, where a moving beam now is) and regions that became darker (`vanished`,
/// where it was). Stationary features cancel.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Changes {
    pub appeared: Vec<BeamSpot>,
    pub vanished: Vec<BeamSpot>,
}

/// The changes from `before` to `after`; empty when the sizes differ.
pub fn changes(before: &Frame, after: &Frame) -> Changes {
    if before.width() != after.width() || before.height() != after.height() {
        return Changes::default();
    }
    let (width, height) = (after.width() as usize, after.height() as usize);
    let gained: Vec<f32> = before
        .pixels()
        .iter()
        .zip(after.pixels())
        .map(|(&b, &a)| f32::from(a) - f32::from(b))
        .collect();
    let (_, noise) = background_and_noise(&gained);
    let lost: Vec<f32> = gained.iter().map(|v| -v).collect();
    Changes {
        appeared: segment(&gained, width, height, 0.0, noise),
        vanished: segment(&lost, width, height, 0.0, noise),
    }
}

/// The centroid of the saturated pixels (255), when there are at least `min_pixels`.
pub fn saturated_centre(frame: &Frame, min_pixels: usize) -> Option<[f64; 2]> {
    let width = frame.width() as usize;
    let (mut n, mut sx, mut sy) = (0usize, 0.0, 0.0);
    for (i, &p) in frame.pixels().iter().enumerate() {
        if p == u8::MAX {
            n += 1;
            sx += (i % width) as f64 + 0.5;
            sy += (i / width) as f64 + 0.5;
        }
    }
    (n >= min_pixels.max(1)).then(|| [sx / n as f64, sy / n as f64])
}

/// The beam nearest to `point`.
pub fn nearest(beams: &[BeamSpot], point: [f64; 2]) -> Option<&BeamSpot> {
    beams.iter().min_by(|a, b| {
        let d = |s: &BeamSpot| (s.centre[0] - point[0]).hypot(s.centre[1] - point[1]);
        d(a).total_cmp(&d(b))
    })
}

/// Bright regions of `values` over `background` with read noise `noise`, brightest first.
fn segment(
    values: &[f32],
    width: usize,
    height: usize,
    background: f64,
    noise: f64,
) -> Vec<BeamSpot> {
    let threshold = background + THRESHOLD_NOISES * noise.max(1.0);
    // Block means: speckle grains merge into one cloud, and segmentation is cheap.
    let (bw, bh) = (width.div_ceil(BLOCK), height.div_ceil(BLOCK));
    let mut blocks = vec![0f64; bw * bh];
    for y in 0..height {
        let row = &values[y * width..(y + 1) * width];
        let block_row = &mut blocks[(y / BLOCK) * bw..(y / BLOCK + 1) * bw];
        for (x, &v) in row.iter().enumerate() {
            block_row[x / BLOCK] += f64::from(v);
        }
    }
    let block_threshold = background + 3.0 * noise.max(1.0) / BLOCK as f64;
    let bright: Vec<bool> = blocks
        .iter()
        .enumerate()
        .map(|(i, sum)| {
            let (bx, by) = (i % bw, i / bw);
            let area = ((width - bx * BLOCK).min(BLOCK) * (height - by * BLOCK).min(BLOCK)) as f64;
            sum / area > block_threshold
        })
        .collect();
    let mut label = vec![usize::MAX; bw * bh];
    let mut beams = Vec::new();
    for start in 0..bright.len() {
        if !bright[start] || label[start] != usize::MAX {
            continue;
        }
        let region = flood(&bright, &mut label, start, bw, bh, beams.len());
        if region.len() < 3 {
            continue;
        }
        let grid = Grid {
            values,
            width,
            height,
            bw,
            bh,
        };
        if let Some(beam) = measure(&grid, &region, background, threshold) {
            beams.push(beam);
        }
    }
    beams.sort_by(|a, b| b.signal.total_cmp(&a.signal));
    // Noise can cluster into tiny regions; a beam carries a real share of the light.
    let strongest = beams.first().map_or(0.0, |b| b.signal);
    beams.retain(|b| b.signal >= MIN_SHARE * strongest && b.signal >= MIN_SIGNAL);
    beams
}

/// Median and a robust spread (median absolute deviation) of the values.
fn background_and_noise(values: &[f32]) -> (f64, f64) {
    if values.is_empty() {
        return (0.0, 0.0);
    }
    let mut sorted = values.to_vec();
    let mid = sorted.len() / 2;
    let median = *sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
    let mut deviations: Vec<f32> = values.iter().map(|v| (v - median).abs()).collect();
    let mad = *deviations.select_nth_unstable_by(mid, f32::total_cmp).1;
    (f64::from(median), 1.4826 * f64::from(mad))
}

/// Labels the 8-connected bright region containing `start`; returns its block indices.
fn flood(
    bright: &[bool],
    label: &mut [usize],
    start: usize,
    bw: usize,
    bh: usize,
    id: usize,
) -> Vec<usize> {
    let mut region = vec![start];
    label[start] = id;
    let mut next = 0;
    while next < region.len() {
        let index = region[next];
        next += 1;
        let (x, y) = ((index % bw) as isize, (index / bw) as isize);
        for (dx, dy) in [
            (-1, -1),
            (0, -1),
            (1, -1),
            (-1, 0),
            (1, 0),
            (-1, 1),
            (0, 1),
            (1, 1),
        ] {
            let (nx, ny) = (x + dx, y + dy);
            if nx < 0 || ny < 0 || nx >= bw as isize || ny >= bh as isize {
                continue;
            }
            let neighbour = ny as usize * bw + nx as usize;
            if bright[neighbour] && label[neighbour] == usize::MAX {
                label[neighbour] = id;
                region.push(neighbour);
            }
        }
    }
    region
}

/// The image and its block grid.
struct Grid<'a> {
    values: &'a [f32],
    width: usize,
    height: usize,
    bw: usize,
    bh: usize,
}

/// Centroid, spread and shape of a region from its full-resolution pixels.
fn measure(grid: &Grid, region: &[usize], background: f64, threshold: f64) -> Option<BeamSpot> {
    let (mut sum, mut sx, mut sy, mut sxx) = (0.0, 0.0, 0.0, 0.0);
    let (mut core, mut roughness) = (0.0, 0.0);
    let (mut brightest, mut at_brightest) = (f64::MIN, 0usize);
    let mut clipped = false;
    for &block in region {
        let (bx, by) = (block % grid.bw, block / grid.bw);
        clipped |= bx == 0 || by == 0 || bx + 1 == grid.bw || by + 1 == grid.bh;
        for (x, y, raw) in grid.block_pixels(block) {
            let value = raw - background;
            if value <= 0.0 {
                continue;
            }
            let (px, py) = (x as f64 + 0.5, y as f64 + 0.5);
            sum += value;
            sx += value * px;
            sy += value * py;
            sxx += value * (px * px + py * py);
            if raw > threshold && x + 1 < grid.width {
                core += value;
                roughness += (f64::from(grid.values[y * grid.width + x + 1]) - raw).abs();
            }
            if raw > brightest {
                (brightest, at_brightest) = (raw, 0);
            }
            if raw == brightest {
                at_brightest += 1;
            }
        }
    }
    if sum <= 0.0 {
        return None;
    }
    let centre = [sx / sum, sy / sum];
    let radius = (sxx / sum - centre[0].powi(2) - centre[1].powi(2))
        .max(0.0)
        .sqrt();
    // A spot is smooth: neighbouring pixels differ little compared with the light they
    // carry. Speckle grains make neighbours differ by about as much as the light itself.
    let localised = core > 0.0 && roughness / core < MAX_SPOT_ROUGHNESS;
    // A plateau at the brightest level is saturation: those pixels carry no shape.
    let saturated = at_brightest >= SATURATION_PLATEAU;
    // The fit runs on block means: sixteen pixels average the read noise down fourfold,
    // and a spot varies little across a block.
    let block_noise = (threshold - background) / THRESHOLD_NOISES / BLOCK as f64;
    let floor = (FIT_FLOOR_NOISES * block_noise).max(FIT_FLOOR_SHARE * (brightest - background));
    let mut fitter = GaussianFitter::new(centre, radius);
    for &block in region {
        let (mut n, mut total, mut bx, mut by, mut clamped) = (0.0, 0.0, 0.0, 0.0, false);
        for (x, y, raw) in grid.block_pixels(block) {
            n += 1.0;
            total += raw - background;
            bx += x as f64 + 0.5;
            by += y as f64 + 0.5;
            clamped |= saturated && raw >= brightest;
        }
        if n > 0.0 && !clamped && total / n > floor {
            fitter.add(bx / n, by / n, total / n);
        }
    }
    let fit = fitter
        .finish(block_noise)
        .filter(|f| f.radius < MAX_FIT_RADIUS_SHARE * radius.max(1.0));
    Some(BeamSpot {
        centre,
        signal: sum,
        localised,
        clipped,
        radius,
        fit,
    })
}

impl Grid<'_> {
    /// The full-resolution pixels of one block: (x, y, value).
    fn block_pixels(&self, block: usize) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
        let (x0, y0) = ((block % self.bw) * BLOCK, (block / self.bw) * BLOCK);
        (y0..(y0 + BLOCK).min(self.height)).flat_map(move |y| {
            (x0..(x0 + BLOCK).min(self.width))
                .map(move |x| (x, y, f64::from(self.values[y * self.width + x])))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spot_frame(centre: [f64; 2], radius: f64) -> Frame {
        let (w, h) = (320u32, 240u32);
        let mut pixels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let r2 = (f64::from(x) + 0.5 - centre[0]).powi(2)
                    + (f64::from(y) + 0.5 - centre[1]).powi(2);
                let noise = ((x * 7 + y * 13) % 5) as f64;
                pixels.push(
                    (10.0 + noise + 200.0 * (-2.0 * r2 / radius.powi(2)).exp()).min(255.0) as u8,
                );
            }
        }
        Frame::new(w, h, pixels).unwrap()
    }

    #[test]
    fn finds_a_spot_with_sub_pixel_accuracy() {
        let beams = find_beams(&spot_frame([150.3, 100.7], 20.0));
        assert_eq!(beams.len(), 1);
        let [x, y] = beams[0].centre;
        assert!(
            (x - 150.3).abs() < 0.5 && (y - 100.7).abs() < 0.5,
            "{x} {y}"
        );
        assert!(beams[0].localised && !beams[0].clipped);
    }

    #[test]
    fn a_spot_at_the_border_is_clipped() {
        let beams = find_beams(&spot_frame([5.0, 100.0], 20.0));
        assert!(beams[0].clipped, "{beams:?}");
    }

    #[test]
    fn changes_show_only_what_moved() {
        let before = spot_frame([100.0, 100.0], 15.0);
        let after = spot_frame([200.0, 120.0], 15.0);
        let moved = changes(&before, &after);
        assert_eq!(moved.appeared.len(), 1);
        assert_eq!(moved.vanished.len(), 1);
        assert!((moved.appeared[0].centre[0] - 200.0).abs() < 1.0);
        assert!((moved.vanished[0].centre[0] - 100.0).abs() < 1.0);
        assert!(changes(&before, &before).appeared.is_empty());
    }

    #[test]
    fn a_blank_frame_has_no_beams() {
        let frame = Frame::new(64, 48, (0..64 * 48).map(|i| 10 + (i % 5) as u8).collect()).unwrap();
        assert!(find_beams(&frame).is_empty());
    }

    #[test]
    fn scattered_grains_are_not_a_localised_spot() {
        let (w, h) = (320u32, 240u32);
        let pixels = (0..h)
            .flat_map(|y| (0..w).map(move |x| (x, y)))
            .map(|(x, y)| {
                let grain = (x / 3 + y / 3 * 7) % 3 == 0
                    && (100..220).contains(&x)
                    && (60..180).contains(&y);
                if grain { 120 } else { 10 + ((x + y) % 3) as u8 }
            })
            .collect();
        let beams = find_beams(&Frame::new(w, h, pixels).unwrap());
        assert!(!beams.is_empty());
        assert!(!beams[0].localised, "{beams:?}");
    }
}
