//! A camera frame made ready for measurement: light above a fitted background in gray levels of an
//! 8-bit frame, with its noise, saturation and [`NoiseMap`]. Rules: docs/vision.md, "Seeing beams".

use optalign_optics::Frame;

use super::cells::around;
use super::noise::{NoiseMap, clipped_normal_mean};
use super::tuning::{
    BAND_SHARE, CELL_CLIPPED_SHARE, CELL_OUTLIER, CELLS_PER_SIDE, CLIP_MARGIN, CLIPPED_DARK_SHARE,
    DARKEST_START_SHARE, FIT_ROUNDS, HISTOGRAM_OUTLIER_SPREADS, HOT_NOISES, HOT_RATIO,
    LIFTED_LEVELS, MAX_BINS, MIN_CELL_PX, MIN_KNOWN_SHARE, MIN_NOISE_STEPS, MIN_QUADRATIC_CELLS,
    MISFIT_SIGNIFICANCE, PLANE_ROUNDS, QUADRATIC_GAIN, SATURATION_PLATEAU_PIXELS, STREAK_COLUMNS,
    STREAK_SIGNIFICANCE, TRIMMED_KEEP_SHARE,
};

/// A frame's light above its background.
#[derive(Clone, Debug)]
pub struct Picture {
    width: usize,
    height: usize,
    light: Vec<f32>,
    saturated: Vec<bool>,
    noise: f64,
    noise_map: NoiseMap,
    /// The background the light is measured above.
    plane: Plane,
}

impl Picture {
    /// Measures the background, the noise, streaks and hot pixels of `frame`.
    pub fn new(frame: &Frame) -> Self {
        let (width, height) = (frame.width() as usize, frame.height() as usize);
        let raw = frame.pixels();
        let depth = Depth::of(frame);
        let plane = Plane::fit(raw, width, height, depth);
        let noise = plane.noise;
        let scale = depth.level_per_count as f32;
        let mut light = Vec::with_capacity(raw.len());
        for (y, row) in raw.chunks_exact(width).enumerate() {
            let y = y as f64 + 0.5;
            for (x, &p) in row.iter().enumerate() {
                light.push(f32::from(p) * scale - plane.level_at(x as f64 + 0.5, y) as f32);
            }
        }
        remove_column_streaks(&mut light, width, height, noise);
        repair_hot_pixels(&mut light, width, height, noise);
        let saturation = saturation_value(raw, frame.full_scale());
        let saturated = raw
            .iter()
            .map(|&p| Some(p) == saturation && p > 0)
            .collect();
        let noise_map = if plane.clipped {
            NoiseMap::clipped(frame, noise)
        } else {
            NoiseMap::uniform(width, height, noise)
        };
        Self {
            width,
            height,
            light,
            saturated,
            noise,
            noise_map,
            plane,
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// Light above the background, gray levels, row-major.
    pub fn light(&self) -> &[f32] {
        &self.light
    }

    /// Pixels at the saturation level, row-major.
    pub fn saturated(&self) -> &[bool] {
        &self.saturated
    }

    /// Read noise, gray levels (standard deviation).
    pub fn noise(&self) -> f64 {
        self.noise
    }

    /// How far one pixel's value scatters, place by place (less where black clips the noise).
    pub fn noise_map(&self) -> &NoiseMap {
        &self.noise_map
    }

    /// The background level at the image centre, gray levels.
    pub fn background(&self) -> f64 {
        self.background_at(self.width as f64 / 2.0, self.height as f64 / 2.0)
    }

    /// The background level under pixel position (`x`, `y`), gray levels.
    pub fn background_at(&self, x: f64, y: f64) -> f64 {
        self.plane.level_at(x, y)
    }

    /// The background's scatter about its surface beyond the noise, gray levels (0 once taken off).
    pub fn background_misfit(&self) -> f64 {
        self.plane.misfit
    }

    /// This picture with `light` (stationary light taken off), `noise` and `noise_map`.
    pub fn with_light(&self, light: Vec<f32>, noise: f64, noise_map: NoiseMap) -> Self {
        Self {
            light,
            noise,
            noise_map,
            saturated: self.saturated.clone(),
            plane: Plane {
                misfit: 0.0,
                ..self.plane
            },
            ..*self
        }
    }

    /// The same measurement for a frames' difference `light`: nothing saturated.
    pub(crate) fn with_difference(&self, light: Vec<f32>, noise: f64, noise_map: NoiseMap) -> Self {
        Self {
            saturated: vec![false; light.len()],
            light,
            noise,
            noise_map,
            plane: Plane {
                surface: Surface::new(self.width, self.height, 0),
                noise,
                clipped: false,
                misfit: 0.0,
            },
            ..*self
        }
    }
}

/// The saturation value, if any: the top value when `full_scale` or piled above the next present.
fn saturation_value(raw: &[u16], full_scale: u16) -> Option<u16> {
    let top = raw.iter().copied().max()?;
    let plateau = raw.iter().filter(|&&p| p == top).count();
    let below = raw.iter().copied().filter(|&p| p < top).max();
    let below_count = below.map_or(0, |b| raw.iter().filter(|&&p| p == b).count());
    let piled_up = plateau >= SATURATION_PLATEAU_PIXELS && plateau > below_count;
    (top == full_scale || piled_up).then_some(top)
}

/// How a frame's counts become gray levels, and the histogram bins its statistics use.
#[derive(Clone, Copy, Debug)]
struct Depth {
    /// Gray levels of an 8-bit frame per count.
    level_per_count: f64,
    bin_counts: u16,
    bins: usize,
}

impl Depth {
    fn of(frame: &Frame) -> Self {
        let values = u32::from(frame.full_scale()) + 1;
        let bin_counts = values.div_ceil(MAX_BINS).max(1);
        Self {
            level_per_count: f64::from(frame.levels_per_count()),
            bin_counts: bin_counts as u16,
            bins: values.div_ceil(bin_counts) as usize,
        }
    }
}

/// A background `a + b u + c v` (+ `d u² + e u v + f v²`), `u`, `v` from -1 to 1 across the frame.
#[derive(Clone, Copy, Debug)]
struct Surface {
    coefficients: [f64; 6],
    /// Terms used: 3 (a plane) or 6.
    terms: usize,
    half: [f64; 2],
}

impl Surface {
    fn new(width: usize, height: usize, terms: usize) -> Self {
        Self {
            coefficients: [0.0; 6],
            terms,
            half: [width as f64 / 2.0, height as f64 / 2.0],
        }
    }

    fn terms_at(&self, x: f64, y: f64) -> [f64; 6] {
        let (u, v) = (x / self.half[0] - 1.0, y / self.half[1] - 1.0);
        [1.0, u, v, u * u, u * v, v * v]
    }

    fn at(&self, x: f64, y: f64) -> f64 {
        let t = self.terms_at(x, y);
        (0..self.terms).map(|k| self.coefficients[k] * t[k]).sum()
    }
}

/// The background surface and read noise; `clipped` when black clips the background's pixels.
#[derive(Clone, Copy, Debug)]
struct Plane {
    surface: Surface,
    noise: f64,
    clipped: bool,
    /// The cells' scatter about the surface beyond their noise, gray levels: structure.
    misfit: f64,
}

impl Plane {
    /// The background a pixel at (`x`, `y`) shows: the surface, or its clipped mean where clipped.
    fn level_at(&self, x: f64, y: f64) -> f64 {
        let level = self.surface.at(x, y);
        if self.clipped {
            self.noise * clipped_normal_mean(level / self.noise)
        } else {
            level
        }
    }

    /// Fits the background to cell levels, rejecting cells with light, and measures the noise.
    fn fit(raw: &[u16], width: usize, height: usize, depth: Depth) -> Self {
        let short = width.min(height);
        let cell = (short / CELLS_PER_SIDE).max(MIN_CELL_PX).min(short.max(1));
        let (cw, ch) = (width.div_ceil(cell), height.div_ceil(cell));
        let mut cells = Vec::with_capacity(cw * ch);
        for cy in 0..ch {
            for cx in 0..cw {
                let mut histogram = Histogram::new(depth);
                let (x0, y0) = (cx * cell, cy * cell);
                let (x1, y1) = ((x0 + cell).min(width), (y0 + cell).min(height));
                for y in (y0..y1).step_by(2) {
                    for &p in raw[y * width + x0..y * width + x1].iter().step_by(2) {
                        histogram.add(p);
                    }
                }
                let above_black = histogram.above_black();
                let black = histogram.counts[0];
                // Black clips many pixels: the level is read above black (it may lie below 0).
                let level = if f64::from(black) > CELL_CLIPPED_SHARE * f64::from(histogram.total) {
                    above_black.map(|(level, _)| level)
                } else {
                    Some(histogram.robust_mean())
                };
                cells.push(Cell {
                    centre: [(x0 + x1) as f64 / 2.0, (y0 + y1) as f64 / 2.0],
                    level,
                    bounds: [x0, y0, x1, y1],
                    black,
                    total: histogram.total,
                    noise_above_black: above_black.map(|(_, noise)| noise),
                });
            }
        }
        // A camera whose black clips nearly the whole background: its level is black.
        let unknown = cells.iter().filter(|c| c.level.is_none()).count();
        if (unknown as f64) > (1.0 - MIN_KNOWN_SHARE) * cells.len() as f64 {
            for cell in cells.iter_mut().filter(|c| c.level.is_none()) {
                cell.level = Some(0.0);
            }
        }
        // Light only adds: a clearly lower fit from the darkest cells beats one on spots' tails.
        let known: Vec<bool> = cells.iter().map(|c| c.level.is_some()).collect();
        let flat = Surface::new(width, height, 3);
        let (mut plane, mut keep) = robust_surface(&cells, flat, known, PLANE_ROUNDS);
        let levels = cells.iter().filter_map(|c| c.level).collect();
        let darkest = quantile_of(levels, DARKEST_START_SHARE);
        let dark: Vec<bool> = cells
            .iter()
            .map(|c| c.level.zip(darkest).is_some_and(|(l, d)| l <= d))
            .collect();
        let (low, low_keep) = robust_surface(&cells, flat, dark, FIT_ROUNDS);
        let centre = |s: &Surface| s.at(width as f64 / 2.0, height as f64 / 2.0);
        if centre(&low) < centre(&plane) - LIFTED_LEVELS {
            (plane, keep) = (low, low_keep);
        }
        let mut differences = Histogram::new(depth);
        let kept_cells = || kept(&cells, &keep);
        for &[x0, y0, x1, y1] in kept_cells().map(|c| &c.bounds) {
            for y in (y0..y1).step_by(3) {
                let row = &raw[y * width..(y + 1) * width];
                for x in (x0..x1.min(width - 1)).step_by(2) {
                    differences.add(row[x + 1].abs_diff(row[x]));
                }
            }
        }
        let (black, total) = kept_cells().fold((0, 0), |(b, t), c| (b + c.black, t + c.total));
        let clipped = f64::from(black) > CLIPPED_DARK_SHARE * f64::from(total);
        let noise = clipped
            .then(|| median(kept_cells().filter_map(|c| c.noise_above_black).collect()))
            .flatten()
            .unwrap_or_else(|| differences.noise_from_differences())
            .max(MIN_NOISE_STEPS * depth.level_per_count);
        // A cell's level averages about `samples` pixels: that much of its scatter is noise.
        let samples = kept_cells().map(|c| f64::from(c.total)).sum::<f64>()
            / kept_cells().count().max(1) as f64;
        let cell_noise = noise / samples.max(1.0).sqrt();
        let misfit_of = |surface: &Surface, keep: &[bool]| {
            let residual = |c: &Cell| c.level.map(|l| l - surface.at(c.centre[0], c.centre[1]));
            let spread = robust_spread(kept(&cells, keep).filter_map(residual));
            if spread > MISFIT_SIGNIFICANCE * cell_noise {
                (spread.powi(2) - cell_noise.powi(2)).sqrt()
            } else {
                0.0
            }
        };
        let mut misfit = misfit_of(&plane, &keep);
        // A glow bending across the frame: a quadratic, if it explains most of what the plane left.
        let quadratic = Surface { terms: 6, ..plane };
        let (bowl, bowl_keep) = robust_surface(&cells, quadratic, keep, FIT_ROUNDS);
        let bowl_misfit = misfit_of(&bowl, &bowl_keep);
        if bowl_keep.iter().filter(|k| **k).count() >= MIN_QUADRATIC_CELLS
            && bowl_misfit <= QUADRATIC_GAIN * misfit
        {
            (plane, misfit) = (bowl, bowl_misfit);
        }
        Self {
            surface: plane,
            noise,
            clipped,
            misfit,
        }
    }
}

/// A background cell: its level, bounds `[x0, y0, x1, y1)`, samples at 0 of all, noise above black.
struct Cell {
    centre: [f64; 2],
    /// The background level, `None` when nearly everything reads black.
    level: Option<f64>,
    bounds: [usize; 4],
    black: u32,
    total: u32,
    noise_above_black: Option<f64>,
}

/// Standard-normal points and cumulative probabilities, half a σ apart (see `above_black`).
const NORMAL_POINTS: [(f64, f64); 5] = [
    (0.0, 0.5),
    (0.5, 0.6915),
    (1.0, 0.8413),
    (1.5, 0.9332),
    (2.0, 0.9772),
];

/// A frame's values binned (one bin per value up to 12 bits) with each bin's sum, in gray levels.
struct Histogram {
    counts: Vec<u32>,
    sums: Vec<u64>,
    total: u32,
    depth: Depth,
}

impl Histogram {
    fn new(depth: Depth) -> Self {
        Self {
            counts: vec![0; depth.bins],
            sums: vec![0; depth.bins],
            total: 0,
            depth,
        }
    }

    fn add(&mut self, value: u16) {
        let bin = usize::from(value / self.depth.bin_counts);
        self.counts[bin] += 1;
        self.sums[bin] += u64::from(value);
        self.total += 1;
    }

    /// The gray level bin `bin` stands for: the mean of its values (its middle when empty).
    fn level(&self, bin: usize) -> f64 {
        let counts = self.depth.bin_counts;
        let value = match self.counts[bin] {
            0 => bin as f64 * f64::from(counts) + f64::from(counts - 1) / 2.0,
            n => self.sums[bin] as f64 / f64::from(n),
        };
        value * self.depth.level_per_count
    }

    /// The bin of the smallest value with at least `share` of the counts at or below it.
    fn quantile_bin(&self, share: f64) -> usize {
        let wanted = (share * f64::from(self.total)).ceil().max(1.0) as u32;
        reaching(&self.counts, wanted).unwrap_or(self.counts.len() - 1)
    }

    /// The mean without hot pixels far above the median: a pixel's level, clipping included.
    fn robust_mean(&self) -> f64 {
        let median_bin = self.quantile_bin(0.5);
        let median = self.level(median_bin);
        let mut deviations = vec![0u32; self.counts.len()];
        for (bin, &count) in self.counts.iter().enumerate() {
            deviations[bin.abs_diff(median_bin)] += count;
        }
        let bin_levels = f64::from(self.depth.bin_counts) * self.depth.level_per_count;
        let mad = reaching(&deviations, self.total.div_ceil(2)).unwrap_or(0) as f64 * bin_levels;
        // Near black half the pixels read 0, shrinking the MAD: the spread above black bounds it.
        let spread = (MAD_TO_SIGMA * mad)
            .max(self.above_black().map_or(0.0, |(_, noise)| noise))
            .max(1.0);
        let limit = median + HISTOGRAM_OUTLIER_SPREADS * spread;
        let (sum, n) = self
            .counts
            .iter()
            .enumerate()
            .map(|(bin, &count)| (self.level(bin), count))
            .filter(|&(level, _)| level <= limit)
            .fold((0.0, 0.0), |(s, n), (level, count)| {
                (s + level * f64::from(count), n + f64::from(count))
            });
        if n == 0.0 { median } else { sum / n }
    }

    /// The level and read noise of values black clips, from two quantiles one σ apart above the
    /// clipped share (quantile p lies at level + z σ); `None` when too little lies above black.
    fn above_black(&self) -> Option<(f64, f64)> {
        let black = f64::from(self.counts[0]) / f64::from(self.total.max(1));
        let lower = NORMAL_POINTS
            .iter()
            .position(|&(_, p)| p > black + CLIP_MARGIN)?;
        let (z_low, p_low) = NORMAL_POINTS[lower];
        let (z_high, p_high) = *NORMAL_POINTS.get(lower + 2)?;
        let [low, high] = [p_low, p_high].map(|p| self.level(self.quantile_bin(p)));
        let noise = (high - low) / (z_high - z_low);
        Some((low - z_low * noise, noise))
    }

    /// The read noise from neighbour differences, whose lower 98 % average 0.953 · 2σ/√π for
    /// Gaussian noise (a mean, not a median: differences are whole counts).
    fn noise_from_differences(&self) -> f64 {
        let mut keep = (f64::from(self.total) * TRIMMED_KEEP_SHARE).ceil() as u32;
        let (mut sum, mut n) = (0.0, 0.0);
        for (bin, &count) in self.counts.iter().enumerate() {
            let taken = count.min(keep);
            sum += self.level(bin) * f64::from(taken);
            n += f64::from(taken);
            keep -= taken;
            if keep == 0 {
                break;
            }
        }
        sum / n.max(1.0) * std::f64::consts::PI.sqrt() / 2.0 / 0.953
    }
}

/// The first bin at which the running total of `counts` reaches `wanted`.
fn reaching(counts: &[u32], wanted: u32) -> Option<usize> {
    let mut seen = 0;
    counts.iter().position(|&count| {
        seen += count;
        seen >= wanted
    })
}

pub(crate) fn kept<'a, T>(items: &'a [T], keep: &'a [bool]) -> impl Iterator<Item = &'a T> {
    items
        .iter()
        .zip(keep)
        .filter_map(|(item, &k)| k.then_some(item))
}

/// The σ of a normal distribution is its median absolute deviation times this.
const MAD_TO_SIGMA: f64 = 1.4826;

/// The σ of `residuals` about 0, robustly (0 when there are none).
pub(crate) fn robust_spread(residuals: impl Iterator<Item = f64>) -> f64 {
    MAD_TO_SIGMA * median(residuals.map(f64::abs).collect()).unwrap_or(0.0)
}

/// The median of the values (the upper one of an even count), or `None` when there are none.
pub fn median(values: Vec<f64>) -> Option<f64> {
    quantile_of(values, 0.5)
}

/// The value with `share` of the others below it, or `None` when there are none.
fn quantile_of(mut values: Vec<f64>, share: f64) -> Option<f64> {
    let last = values.len().checked_sub(1)?;
    let at = ((share * values.len() as f64) as usize).min(last);
    Some(*values.select_nth_unstable_by(at, f64::total_cmp).1)
}

/// `surface` fitted from the cells in `keep`, refitted by residual for up to `rounds` rounds.
fn robust_surface(
    cells: &[Cell],
    mut surface: Surface,
    mut keep: Vec<bool>,
    rounds: usize,
) -> (Surface, Vec<bool>) {
    for _ in 0..rounds {
        fit_least_squares(&mut surface, cells, &keep);
        let residuals: Vec<f64> = cells
            .iter()
            .map(|c| {
                c.level.map_or(f64::INFINITY, |level| {
                    level - surface.at(c.centre[0], c.centre[1])
                })
            })
            .collect();
        let spread = robust_spread(kept(&residuals, &keep).copied());
        let limit = CELL_OUTLIER * spread.max(0.5);
        let next: Vec<bool> = residuals.iter().map(|r| r.abs() <= limit).collect();
        if next == keep || next.iter().filter(|k| **k).count() < surface.terms {
            break;
        }
        keep = next;
    }
    (surface, keep)
}

/// Fits `surface`'s terms to the kept cells' levels by least squares (unchanged if it cannot).
fn fit_least_squares(surface: &mut Surface, cells: &[Cell], keep: &[bool]) {
    let n = surface.terms;
    let mut normal = nalgebra::DMatrix::<f64>::zeros(n, n);
    let mut rhs = nalgebra::DVector::<f64>::zeros(n);
    for cell in kept(cells, keep) {
        let terms = surface.terms_at(cell.centre[0], cell.centre[1]);
        let row = nalgebra::DVector::from_column_slice(&terms[..n]);
        normal += &row * row.transpose();
        rhs += &row * cell.level.unwrap_or(0.0);
    }
    if let Some(cholesky) = normal.cholesky() {
        surface.coefficients[..n].copy_from_slice(cholesky.solve(&rhs).as_slice());
    }
}

/// Removes an offset from each column all four bands show (a smear runs the whole height; beams
/// rarely fill all four bands), significant alone or over [`STREAK_COLUMNS`] (a wide streak).
fn remove_column_streaks(light: &mut [f32], width: usize, height: usize, noise: f64) {
    let band = ((height as f64 * BAND_SHARE) as usize)
        .max(2)
        .min(height / 2);
    if band < 2 {
        return;
    }
    // A median's standard error is about 1.25 times the mean's.
    let limit = (STREAK_SIGNIFICANCE * 1.25 * noise / (band as f64).sqrt()) as f32;
    // Each band's column medians less its typical column: an offset shared by all is background.
    let relative = |first_row: usize| {
        // Column by column, each column's `band` pixels in a run.
        let mut pixels: Vec<f32> = (0..band * width)
            .map(|i| light[(first_row + i % band) * width + i / band])
            .collect();
        let mut medians: Vec<f32> = pixels.chunks_exact_mut(band).map(median_f32).collect();
        let typical = median_f32(&mut medians.clone());
        medians.iter_mut().for_each(|m| *m -= typical);
        medians
    };
    let bottom = height - band;
    let bands = [0, bottom / 3, 2 * bottom / 3, bottom].map(relative);
    let offsets: Vec<f32> = (0..width)
        .map(|x| {
            // The smallest offset, taken only when every band agrees on its sign.
            let (low, high) = bands.iter().fold((f32::MAX, f32::MIN), |(lo, hi), b| {
                (lo.min(b[x]), hi.max(b[x]))
            });
            if low > 0.0 {
                low
            } else if high < 0.0 {
                high
            } else {
                0.0
            }
        })
        .collect();
    let half = STREAK_COLUMNS / 2;
    let wide_limit = limit / (STREAK_COLUMNS as f32).sqrt();
    let offsets: Vec<f32> = (0..width)
        .map(|x| {
            let own = offsets[x];
            let around = &offsets[x.saturating_sub(half)..(x + half + 1).min(width)];
            let mean = around.iter().sum::<f32>() / around.len() as f32;
            if own.abs() > limit {
                own
            } else if mean.abs() > wide_limit {
                mean
            } else {
                0.0
            }
        })
        .collect();
    if offsets.iter().all(|&o| o == 0.0) {
        return;
    }
    for (v, o) in light.iter_mut().zip(offsets.iter().cycle()) {
        *v -= o;
    }
}

/// The median of a slice (reordered).
pub(crate) fn median_f32(values: &mut [f32]) -> f32 {
    let mid = values.len() / 2;
    *values.select_nth_unstable_by(mid, f32::total_cmp).1
}

/// Replaces hot pixels, single or paired (far above all but one of 8 neighbours), by their median.
fn repair_hot_pixels(light: &mut [f32], width: usize, height: usize, noise: f64) {
    let floor = (HOT_NOISES * noise) as f32;
    let mut ring = Vec::with_capacity(8);
    for i in 0..light.len() {
        let v = light[i];
        if v <= floor {
            continue;
        }
        // Inside a beam both horizontal neighbours are nearly as bright: not a hot pixel.
        let quick = (v - floor / 2.0) / HOT_RATIO;
        if i > 0 && i + 1 < light.len() && light[i - 1] >= quick && light[i + 1] >= quick {
            continue;
        }
        ring.clear();
        for n in around(i, 1, width, height).filter(|&n| n != i) {
            ring.push(light[n]);
        }
        if ring.len() < 3 {
            continue;
        }
        ring.sort_by(f32::total_cmp);
        let second = ring[ring.len() - 2];
        if v > HOT_RATIO * second.max(0.0) + floor / 2.0 {
            light[i] = ring[ring.len() / 2];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::synthetic::Scene;

    #[test]
    fn a_sloping_background_and_its_noise_are_measured() {
        let frame = Scene::new(400, 300)
            .background(30.0, [0.08, -0.05])
            .noise(4.0, 1)
            .frame();
        let picture = Picture::new(&frame);
        assert!((picture.noise() - 4.0).abs() < 0.4, "{}", picture.noise());
        assert!(
            (picture.background() - 30.0).abs() < 1.0,
            "{}",
            picture.background()
        );
        let light = picture.light();
        let mean = light.iter().map(|&v| f64::from(v)).sum::<f64>() / light.len() as f64;
        assert!(mean.abs() < 0.5, "{mean}");
        // Corners too: the slope is gone everywhere.
        let corner = (0..20)
            .flat_map(|y| (0..20).map(move |x| (x, y)))
            .map(|(x, y)| f64::from(light[y * 400 + 380 + x]))
            .sum::<f64>()
            / 400.0;
        assert!(corner.abs() < 1.5, "{corner}");
    }

    #[test]
    fn spots_whose_tails_cover_most_of_the_frame_do_not_lift_the_background() {
        // The relay's frame at its near station with three stray spots: a beam of 100 px
        // and three spots of 80 px, whose faint tails reach over most cells.
        let frame = Scene::new(640, 480)
            .background(6.0, [0.0, 0.0])
            .gaussian([291.0, 201.0], 100.0, 220.0)
            .gaussian([518.0, 110.0], 80.0, 176.0)
            .gaussian([90.0, 346.0], 80.0, 176.0)
            .gaussian([397.0, 413.0], 80.0, 176.0)
            .noise(2.5, 4)
            .frame();
        let picture = Picture::new(&frame);
        assert!(
            (picture.background() - 6.0).abs() < 1.0,
            "{}",
            picture.background()
        );
    }

    #[test]
    fn a_beam_does_not_pull_the_background_up() {
        let frame = Scene::new(400, 300)
            .background(10.0, [0.0, 0.0])
            .gaussian([200.0, 150.0], 60.0, 150.0)
            .noise(2.0, 2)
            .frame();
        let picture = Picture::new(&frame);
        assert!(
            (picture.background() - 10.0).abs() < 0.5,
            "{}",
            picture.background()
        );
    }

    #[test]
    fn hot_pixels_and_smear_columns_are_removed() {
        let frame = Scene::new(300, 200)
            .background(10.0, [0.0, 0.0])
            .hot_pixels(50, 200.0, 3)
            .smear_column(120, 6, 40.0)
            .noise(2.0, 4)
            .frame();
        let picture = Picture::new(&frame);
        let worst = picture.light().iter().copied().fold(0f32, f32::max);
        assert!(worst < 20.0, "brightest remaining {worst}");
    }
}
