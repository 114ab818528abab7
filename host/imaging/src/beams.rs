//! Finding beams in a [`Picture`]: bright regions on a block grid, joined into beams, each
//! measured the ISO 11146 way (centroid, second moments) with its centre's uncertainty and flags.

use super::cells::{CellSums, around};
use super::core::pixel_range;
use super::gaussian::{GaussianFit, GaussianFitter};
use super::picture::Picture;
use super::tuning::{
    BLOCK, CLIPPED_SHARE, CORE_PROMINENCE_NOISES, CORE_SHARE, FIT_FLOOR_NOISES, FIT_FLOOR_SHARE,
    JOIN_GAP_SHARE, JOIN_NODE_SHARE, JOIN_PEAK_SHARE, JOIN_VALLEY_NOISES, MAX_FIT_RADIUS_SHARE,
    MAX_SPOT_ROUGHNESS, MIN_MOMENT_VARIANCE_PX2, MIN_REGION_BLOCKS, MIN_SHARE, MIN_SIGNIFICANCE,
    MOMENT_FLOOR_MISFITS, MOMENT_WINDOW_RADII, SATURATED_PIXELS, SETTLED_PX,
    SPLIT_CELLS_PER_RADIUS, SPLIT_CLASSES, THRESHOLD_NOISES,
};

/// A beam found in a picture.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct Beam {
    /// Intensity centroid, px (x right, y down); pulled inwards when the border cuts the beam.
    pub centre: [f64; 2],
    /// Standard uncertainty of the centre, px: the root of the trace of `covariance`.
    pub uncertainty: f64,
    /// Covariance of the centre, px²: read noise and background misfit, widened by texture.
    pub covariance: [[f64; 2]; 2],
    /// Second-moment (1/e²) radii along the principal axes (major, minor), px.
    pub radii: [f64; 2],
    /// Direction of the major axis, degrees from +x towards +y.
    pub angle_deg: f64,
    /// Summed light above the background.
    pub signal: f64,
    /// Brightest block mean above the background, gray levels.
    pub peak: f64,
    /// It holds saturated pixels (its core carries no shape).
    pub saturated: bool,
    /// The image border cuts it: still brighter than a few per cent of its peak there.
    pub clipped: bool,
    /// How bright it still is at the border, as a share of its peak (0: clear of it).
    pub edge_level: f64,
    /// A compact spot rather than a speckle cloud.
    pub localised: bool,
    /// Separate regions joined into it (lobes, stripes between dark fringes).
    pub parts: usize,
    /// A Gaussian fitted to its unsaturated light, for a beam the border cuts.
    pub fit: Option<GaussianFit>,
}

impl Beam {
    /// The geometric mean of the two radii, px.
    pub fn size(&self) -> f64 {
        (self.radii[0] * self.radii[1]).sqrt()
    }

    /// What a user should know before trusting the centre (empty: nothing).
    pub fn notes(&self) -> String {
        let cut = || {
            let fit = self.fit.map_or(String::new(), |f| {
                format!(", Gaussian fit at {:.1},{:.1}", f.centre[0], f.centre[1])
            });
            format!(
                "cut by the border ({:.0}% of peak there{fit})",
                100.0 * self.edge_level
            )
        };
        let notes: Vec<String> = [
            self.saturated.then(|| "saturated".to_string()),
            self.clipped.then(cut),
            (!self.localised).then(|| "speckle, not a compact spot".to_string()),
            (self.parts > 1).then(|| format!("{} lobes joined", self.parts)),
        ]
        .into_iter()
        .flatten()
        .collect();
        notes.join("; ")
    }

    /// The same beam moved by `by`, px.
    pub fn translated(&self, by: [f64; 2]) -> Beam {
        let moved = |p: [f64; 2]| [p[0] + by[0], p[1] + by[1]];
        Beam {
            centre: moved(self.centre),
            fit: self.fit.map(|f| GaussianFit {
                centre: moved(f.centre),
                ..f
            }),
            ..*self
        }
    }
}

/// When separate bright regions are parts of one beam.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Joining {
    /// Cores near and a dark valley between: in a frame, beams whose tails overlap stay apart.
    AcrossDarkValley,
    /// Cores near: on a side of a difference, texture breaks a moved beam into touching pieces.
    Near,
}

/// Beams in `picture`, strongest first, on blocks averaged 3 x 3 (12 px: compact beams apart).
pub fn find_beams(picture: &Picture) -> Vec<Beam> {
    beams_in(picture, 1, Joining::AcrossDarkValley)
}

/// As [`find_beams`] for one side of a frames' difference: regions joined by nearness alone.
pub fn find_changed(picture: &Picture) -> Vec<Beam> {
    beams_in(picture, 1, Joining::Near)
}

/// As [`find_changed`], else on averages twice as wide each time up to about `radius` px (against
/// the noise map): a faint broad beam shows only on averages of about its size.
pub fn find_faint_beams(picture: &Picture, radius: f64) -> Vec<Beam> {
    let widest = (radius / (2 * BLOCK) as f64).round().max(2.0) as usize;
    let mut reach = 1;
    loop {
        let beams = beams_in(picture, reach, Joining::Near);
        if !beams.is_empty() || reach >= widest {
            return beams;
        }
        reach = (2 * reach).min(widest);
    }
}

fn beams_in(picture: &Picture, reach: usize, joining: Joining) -> Vec<Beam> {
    let grid = Grid::new(picture, reach);
    let groups = join_regions(&grid, &grid.regions(), joining);
    let owner = grid.partition(&groups);
    let mut beams: Vec<Beam> = groups
        .iter()
        .enumerate()
        .filter_map(|(id, (blocks, parts))| measure(&grid, &owner, id, blocks, *parts))
        .collect();
    beams.sort_by(|a, b| b.signal.total_cmp(&a.signal));
    let strongest = beams.first().map_or(0.0, |b| b.signal);
    beams.retain(|b| b.signal >= MIN_SHARE * strongest);
    beams
}

/// A picture reduced to block means.
struct Grid<'a> {
    picture: &'a Picture,
    bw: usize,
    bh: usize,
    means: Vec<f32>,
    /// Block means averaged with their neighbours: what regions are found on.
    smooth: Vec<f32>,
    pixel_noise: Vec<f32>,
    /// Noise of each smoothed block: its pixels' noise and the background's misfit.
    smooth_noise: Vec<f32>,
    /// Blocks averaged either side of a block in `smooth`.
    reach: usize,
}

/// A connected bright region of blocks.
struct Region {
    blocks: Vec<usize>,
    peak: f32,
    /// Blocks of the core on its edge (a core block with a non-core neighbour).
    core_edge: Vec<usize>,
    centre: [f64; 2],
}

impl<'a> Grid<'a> {
    fn new(picture: &'a Picture, reach: usize) -> Self {
        let (width, height) = (picture.width(), picture.height());
        let blocks = CellSums::new(picture.light(), width, height, BLOCK, |run: &[f32]| {
            f64::from(run.iter().sum::<f32>())
        });
        let (bw, bh) = (blocks.columns, blocks.rows);
        let means: Vec<f32> = blocks.means().map(|m| m as f32).collect();
        // Finest: one read noise keeps regions (the pixel window's start) tight; wider: noise map.
        let map = picture.noise_map();
        let pixel_noise: Vec<f32> = if reach > 1 {
            (0..bw * bh)
                .map(|b| map.at((b % bw) * BLOCK + BLOCK / 2, (b / bw) * BLOCK + BLOCK / 2))
                .collect()
        } else {
            vec![picture.noise() as f32; bw * bh]
        };
        let side = ((2 * reach + 1) * BLOCK) as f32;
        let misfit = picture.background_misfit() as f32;
        let (smooth, smooth_noise): (Vec<f32>, Vec<f32>) = if reach == 1 {
            (0..bw * bh)
                .map(|b| {
                    let (sum, variance, n) = around(b, 1, bw, bh)
                        .fold((0f32, 0f32, 0f32), |(s, v, n), i| {
                            (s + means[i], v + pixel_noise[i].powi(2), n + 1.0)
                        });
                    (sum / n, ((variance / n).sqrt() / side).hypot(misfit))
                })
                .unzip()
        } else {
            let variances: Vec<f32> = pixel_noise.iter().map(|v| v * v).collect();
            let smooth_noise = box_means(&variances, bw, bh, reach)
                .into_iter()
                .map(|v| (v.sqrt() / side).hypot(misfit))
                .collect();
            (box_means(&means, bw, bh, reach), smooth_noise)
        };
        Self {
            picture,
            bw,
            bh,
            means,
            smooth,
            pixel_noise,
            smooth_noise,
            reach,
        }
    }

    fn centre_of(&self, block: usize) -> [f64; 2] {
        [block % self.bw, block / self.bw].map(|i| (i * BLOCK) as f64 + BLOCK as f64 / 2.0)
    }

    /// Σ v, Σ v x and Σ v y over the centres of `blocks`, `v` the `weight` of each.
    fn weighted(&self, blocks: &[usize], weight: impl Fn(usize) -> f64) -> [f64; 3] {
        blocks.iter().fold([0.0; 3], |[s, sx, sy], &b| {
            let (v, c) = (weight(b), self.centre_of(b));
            [s + v, sx + v * c[0], sy + v * c[1]]
        })
    }

    /// Grows `blocks` breadth-first over `free` blocks `joins` accepts, each taking its parent's
    /// label (so seeds must not be `free`); the blocks reached, in order.
    fn grow<L: Copy + PartialEq>(
        &self,
        label: &mut [L],
        free: L,
        mut blocks: Vec<usize>,
        joins: impl Fn(usize) -> bool,
    ) -> Vec<usize> {
        let mut next = 0;
        while let Some(&block) = blocks.get(next) {
            next += 1;
            for n in around(block, 1, self.bw, self.bh) {
                if label[n] == free && joins(n) {
                    label[n] = label[block];
                    blocks.push(n);
                }
            }
        }
        blocks
    }

    fn bright(&self, b: usize) -> bool {
        self.smooth[b] > THRESHOLD_NOISES as f32 * self.smooth_noise[b]
    }

    /// 8-connected regions of bright smoothed blocks, with enough light to be real.
    fn regions(&self) -> Vec<Region> {
        let mut seen = vec![false; self.bw * self.bh];
        let mut regions = Vec::new();
        for start in 0..seen.len() {
            if seen[start] || !self.bright(start) {
                continue;
            }
            seen[start] = true;
            let blocks = self.grow(&mut seen, false, vec![start], |n| self.bright(n));
            if blocks.len() < MIN_REGION_BLOCKS {
                continue;
            }
            let light: f64 = blocks
                .iter()
                .map(|&b| f64::from(self.means[b]) * (BLOCK * BLOCK) as f64)
                .sum();
            let noise = blocks
                .iter()
                .map(|&b| f64::from(self.pixel_noise[b]).powi(2) * (BLOCK * BLOCK) as f64)
                .sum::<f64>()
                .sqrt();
            if light < MIN_SIGNIFICANCE * noise {
                continue;
            }
            regions.extend(self.split(blocks).into_iter().map(|b| self.describe(b)));
        }
        regions
    }

    /// Splits a region at its prominent cores (beams whose tails touch); each takes its nearest.
    fn split(&self, blocks: Vec<usize>) -> Vec<Vec<usize>> {
        const OUTSIDE: u32 = u32::MAX;
        const UNCLAIMED: u32 = u32::MAX - 1;
        const FAINT_CORE: u32 = u32::MAX - 2;
        let level = CORE_SHARE * brightest(&self.smooth, &blocks);
        let in_core = |b: usize| self.smooth[b] >= level;
        let mut label = vec![OUTSIDE; self.bw * self.bh];
        blocks.iter().for_each(|&b| label[b] = UNCLAIMED);
        let mut seeds = Vec::new();
        let mut cores = 0u32;
        for &start in &blocks {
            if label[start] != UNCLAIMED || self.smooth[start] < level {
                continue;
            }
            label[start] = cores;
            let core = self.grow(&mut label, UNCLAIMED, vec![start], in_core);
            let core_peak = brightest_block(&self.smooth, &core).unwrap_or(start);
            let prominent = level + CORE_PROMINENCE_NOISES * self.smooth_noise[core_peak];
            if core.len() < 2 || self.smooth[core_peak] < prominent {
                core.iter().for_each(|&b| label[b] = FAINT_CORE);
                continue;
            }
            seeds.extend(core);
            cores += 1;
        }
        if cores < 2 {
            return vec![blocks];
        }
        for l in label.iter_mut().filter(|l| **l == FAINT_CORE) {
            *l = UNCLAIMED;
        }
        self.grow(&mut label, UNCLAIMED, seeds, |_| true);
        let mut parts = vec![Vec::new(); cores as usize];
        // The region is connected: every block of it was reached from a core.
        for b in blocks {
            parts[label[b] as usize].push(b);
        }
        parts
    }

    fn describe(&self, blocks: Vec<usize>) -> Region {
        let peak = brightest(&self.smooth, &blocks);
        let core = |b: usize| self.smooth[b] >= CORE_SHARE * peak;
        let core_blocks: Vec<usize> = blocks.iter().copied().filter(|&b| core(b)).collect();
        let [sum, sx, sy] = self.weighted(&core_blocks, |b| f64::from(self.smooth[b]));
        let core_edge = core_blocks
            .into_iter()
            .filter(|&b| around(b, 1, self.bw, self.bh).any(|n| !core(n)))
            .collect();
        Region {
            centre: [sx / sum.max(1e-9), sy / sum.max(1e-9)],
            blocks,
            peak,
            core_edge,
        }
    }

    /// Every block's beam: the nearest group's, by steps on the block grid.
    fn partition(&self, groups: &[(Vec<usize>, usize)]) -> Vec<u32> {
        let mut owner = vec![u32::MAX; self.bw * self.bh];
        let mut seeds: Vec<usize> = Vec::new();
        for (id, (blocks, _)) in groups.iter().enumerate() {
            blocks.iter().for_each(|&b| owner[b] = id as u32);
            seeds.extend(blocks);
        }
        self.grow(&mut owner, u32::MAX, seeds, |_| true);
        owner
    }
}

fn brightest(values: &[f32], blocks: &[usize]) -> f32 {
    blocks.iter().map(|&b| values[b]).fold(f32::MIN, f32::max)
}

/// Which of `blocks` is the brightest in `values` (the last of equals).
fn brightest_block(values: &[f32], blocks: &[usize]) -> Option<usize> {
    blocks
        .iter()
        .copied()
        .max_by(|&a, &b| values[a].total_cmp(&values[b]))
}

/// The mean of `values` (a `bw` x `bh` grid) over the cells within `reach` of each (running sums).
fn box_means(values: &[f32], bw: usize, bh: usize, reach: usize) -> Vec<f32> {
    let line = |source: &[f32], out: &mut [f32], start: usize, len: usize, stride: usize| {
        let mut prefix = Vec::with_capacity(len + 1);
        prefix.push(0f64);
        for i in 0..len {
            prefix.push(prefix[i] + f64::from(source[start + i * stride]));
        }
        for i in 0..len {
            let (lo, hi) = (i.saturating_sub(reach), (i + reach + 1).min(len));
            out[start + i * stride] = ((prefix[hi] - prefix[lo]) / (hi - lo) as f64) as f32;
        }
    };
    let mut rows = vec![0f32; values.len()];
    for y in 0..bh {
        line(values, &mut rows, y * bw, bw, 1);
    }
    let mut out = vec![0f32; values.len()];
    for x in 0..bw {
        line(&rows, &mut out, x, bh, bw);
    }
    out
}

/// Groups regions of one beam by core gap, peaks and `joining`: each group's blocks and parts.
fn join_regions(grid: &Grid, regions: &[Region], joining: Joining) -> Vec<(Vec<usize>, usize)> {
    let tails: Vec<Option<Tail>> = match joining {
        Joining::AcrossDarkValley => regions.iter().map(|r| Tail::of(grid, r)).collect(),
        Joining::Near => Vec::new(),
    };
    let mut parent: Vec<usize> = (0..regions.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for a in 0..regions.len() {
        for b in a + 1..regions.len() {
            let (ra, rb) = (&regions[a], &regions[b]);
            if ra.peak.min(rb.peak) < JOIN_PEAK_SHARE * ra.peak.max(rb.peak) {
                continue;
            }
            let distance = (ra.centre[0] - rb.centre[0]).hypot(ra.centre[1] - rb.centre[1]);
            if core_gap(grid, ra, rb, JOIN_GAP_SHARE * distance)
                && (joining == Joining::Near || dark_between(grid, ra, rb, [&tails[a], &tails[b]]))
            {
                let (x, y) = (root(&mut parent, a), root(&mut parent, b));
                parent[x] = y;
            }
        }
    }
    let mut groups: Vec<(Vec<usize>, usize)> = Vec::new();
    let mut index = vec![usize::MAX; regions.len()];
    for (r, region) in regions.iter().enumerate() {
        let top = root(&mut parent, r);
        if index[top] == usize::MAX {
            index[top] = groups.len();
            groups.push((Vec::new(), 0));
        }
        let (blocks, parts) = &mut groups[index[top]];
        blocks.extend(&region.blocks);
        *parts += 1;
    }
    groups
}

/// Whether the light between `a` and `b` drops to a node, below [`JOIN_NODE_SHARE`] of their
/// `tails`' sum; true when a tail is unknown (a saturated region's peak is unknown).
fn dark_between(grid: &Grid, a: &Region, b: &Region, tails: [&Option<Tail>; 2]) -> bool {
    let [Some(tail_a), Some(tail_b)] = tails else {
        return true;
    };
    let length = (b.centre[0] - a.centre[0]).hypot(b.centre[1] - a.centre[1]);
    let samples = (2.0 * length / BLOCK as f64).ceil().max(1.0) as usize;
    let block = |v: f64, side: usize| (v.max(0.0) as usize / BLOCK).min(side - 1);
    (0..=samples).any(|k| {
        let t = k as f64 / samples as f64;
        let [x, y] = [0, 1].map(|axis| a.centre[axis] + t * (b.centre[axis] - a.centre[axis]));
        let i = block(y, grid.bh) * grid.bw + block(x, grid.bw);
        let block_noise = f64::from(grid.pixel_noise[i]) / BLOCK as f64;
        let apart = tail_a.at([x, y]) + tail_b.at([x, y]);
        f64::from(grid.means[i]) <= JOIN_NODE_SHARE * apart + JOIN_VALLEY_NOISES * block_noise
    })
}

/// The centroid of blocks' light (negative means as none) and its moments (xx, yy, xy), px².
fn block_moments(grid: &Grid, blocks: &[usize]) -> Option<([f64; 2], [f64; 3])> {
    let light = |b: usize| f64::from(grid.means[b].max(0.0));
    let [s, sx, sy] = grid.weighted(blocks, light);
    if s <= 0.0 {
        return None;
    }
    let centre = [sx / s, sy / s];
    let moments = blocks.iter().fold([0.0; 3], |[xx, yy, xy], &b| {
        let (v, c) = (light(b), grid.centre_of(b));
        let [dx, dy] = [c[0] - centre[0], c[1] - centre[1]];
        [xx + v * dx * dx, yy + v * dy * dy, xy + v * dx * dy]
    });
    Some((centre, moments.map(|m| m / s)))
}

/// A region's light taken for a Gaussian of its brightest block's level and its blocks' moments.
struct Tail {
    peak: f64,
    centre: [f64; 2],
    /// The inverse of the blocks' covariance, px⁻².
    inverse: [[f64; 2]; 2],
}

impl Tail {
    /// `None` when the region is saturated or its blocks do not spread along both axes.
    fn of(grid: &Grid, region: &Region) -> Option<Self> {
        let brightest = brightest_block(&grid.means, &region.blocks)?;
        if block_pixels(brightest, grid).any(|p| grid.picture.saturated()[p]) {
            return None;
        }
        let (centre, [cxx, cyy, cxy]) = block_moments(grid, &region.blocks)?;
        let det = cxx * cyy - cxy * cxy;
        (det > 0.0).then(|| Self {
            peak: f64::from(grid.means[brightest]),
            centre,
            inverse: [[cyy / det, -cxy / det], [-cxy / det, cxx / det]],
        })
    }

    fn at(&self, point: [f64; 2]) -> f64 {
        let d = [point[0] - self.centre[0], point[1] - self.centre[1]];
        let m = &self.inverse;
        let q = d[0] * (m[0][0] * d[0] + m[0][1] * d[1]) + d[1] * (m[1][0] * d[0] + m[1][1] * d[1]);
        self.peak * (-0.5 * q).exp()
    }
}

/// Whether the cores of two regions come within `limit` px of each other.
fn core_gap(grid: &Grid, a: &Region, b: &Region, limit: f64) -> bool {
    let limit2 = limit * limit;
    a.core_edge.iter().any(|&i| {
        let p = grid.centre_of(i);
        b.core_edge.iter().any(|&j| {
            let q = grid.centre_of(j);
            (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) <= limit2
        })
    })
}

/// Sums over the pixels of one beam inside a window.
#[derive(Default)]
struct Moments {
    s: f64,
    sx: f64,
    sy: f64,
    sxx: f64,
    syy: f64,
    sxy: f64,
    n: f64,
    /// Σ dx², Σ dy², Σ dx dy over the pixels summed (offsets from the window's centre).
    gxx: f64,
    gyy: f64,
    gxy: f64,
}

/// The pixels beam `id` owns (by `owner`, on `grid`'s blocks) in the window `centre ± half`.
struct Window<'a> {
    grid: &'a Grid<'a>,
    owner: &'a [u32],
    id: u32,
    centre: [f64; 2],
    half: [f64; 2],
}

/// The pixels of `window` above the moment floor, as row runs: `visit(y, x_from, light)`.
fn owned_runs(window: &Window, mut visit: impl FnMut(usize, usize, &[f32])) {
    let (picture, grid) = (window.grid.picture, window.grid);
    let (w, light) = (picture.width(), picture.light());
    let span = |axis: usize, side: usize| pixel_range(window.centre[axis], window.half[axis], side);
    let (xs, ys) = (span(0, w), span(1, picture.height()));
    let floor = MOMENT_FLOOR_MISFITS * picture.background_misfit() as f32;
    for y in ys {
        let row = (y / BLOCK) * grid.bw..(y / BLOCK + 1) * grid.bw;
        let (block_row, smooth_row) = (&window.owner[row.clone()], &grid.smooth[row]);
        let mut x = xs.start;
        while x < xs.end {
            let block = x / BLOCK;
            let end = ((block + 1) * BLOCK).min(xs.end);
            let above_floor = floor <= 0.0 || smooth_row[block] > floor;
            if block_row[block] == window.id && above_floor {
                visit(y, x, &light[y * w + x..y * w + end]);
            }
            x = end;
        }
    }
}

/// The first and second moments of the pixels of `window`, about its centre.
fn window_moments(window: &Window) -> Moments {
    let centre = window.centre;
    // Per row in f32 (a few hundred terms), summed into the totals in f64.
    let mut rows: Vec<(usize, [f32; 6])> = Vec::new();
    owned_runs(window, |y, from, light| {
        if rows.last().is_none_or(|&(row, _)| row != y) {
            rows.push((y, [0.0; 6]));
        }
        let sums = &mut rows.last_mut().expect("pushed").1;
        for (x, v) in (from..).zip(light) {
            let d = (x as f64 + 0.5 - centre[0]) as f32;
            sums[0] += v;
            sums[1] += v * d;
            sums[2] += v * d * d;
            sums[4] += d;
            sums[5] += d * d;
        }
        sums[3] += light.len() as f32;
    });
    let mut m = Moments::default();
    for (y, sums) in rows {
        let [s, sx, sxx, n, gx, gxx] = sums.map(f64::from);
        let py = y as f64 + 0.5 - centre[1];
        m.s += s;
        m.sx += sx;
        m.sy += s * py;
        m.sxx += sxx;
        m.syy += s * py * py;
        m.sxy += sx * py;
        m.n += n;
        m.gxx += gxx;
        m.gyy += n * py * py;
        m.gxy += gx * py;
    }
    m
}

/// The centroid's covariance, px², from the scatter of nine interleaved classes of `cell` px
/// cells, fine enough that the beam's shape cancels; `None` when a class holds no light.
fn split_covariance(window: &Window, cell: usize) -> Option<[[f64; 2]; 2]> {
    let centre = window.centre;
    // Whole-pixel cells: fractional ones would give a class a pixel more here and there (shape).
    let class_of = |pixel: usize| (pixel / cell) % 3;
    let mut sums = [[0f64; 3]; SPLIT_CLASSES];
    owned_runs(window, |y, from, light| {
        let dy = y as f64 + 0.5 - centre[1];
        let row = 3 * class_of(y);
        for (x, &v) in (from..).zip(light) {
            let dx = x as f64 + 0.5 - centre[0];
            let class = &mut sums[row + class_of(x)];
            let v = f64::from(v);
            class[0] += v;
            class[1] += v * dx;
            class[2] += v * dy;
        }
    });
    if sums.iter().any(|[s, _, _]| *s <= 0.0) {
        return None;
    }
    let centres = sums.map(|[s, sx, sy]| [sx / s, sy / s]);
    let k = SPLIT_CLASSES as f64;
    let mean = [0, 1].map(|a| centres.iter().map(|c| c[a]).sum::<f64>() / k);
    let co = |a: usize, b: usize| {
        centres
            .iter()
            .map(|c| (c[a] - mean[a]) * (c[b] - mean[b]))
            .sum::<f64>()
            / (k * (k - 1.0))
    };
    Some([[co(0, 0), co(0, 1)], [co(0, 1), co(1, 1)]])
}

fn measure(grid: &Grid, owner: &[u32], id: usize, blocks: &[usize], parts: usize) -> Option<Beam> {
    let picture = grid.picture;
    let footprint = if grid.reach > 1 {
        faint_footprint(grid, blocks)?
    } else {
        window_footprint(grid, owner, id as u32, blocks)?
    };
    // cov(cx, cy) = σ² Σ (x - cx)(y - cy) / S², σ the read noise and background misfit together.
    let (signal, split) = (footprint.signal, footprint.split);
    let gain = (picture.noise().hypot(picture.background_misfit()) / signal).powi(2);
    let read = footprint.spread.map(|row| row.map(|g| gain * g));
    let covariance = split.map_or(read, |split| with_texture(read, split));
    let peak = f64::from(brightest(&grid.means, blocks));
    // Judged on smoothed blocks: a speckled beam's brightest raw block is one grain.
    let smooth_peak = f64::from(brightest(&grid.smooth, blocks));
    let at_border = blocks
        .iter()
        .filter(|&&b| {
            let (bx, by) = (b % grid.bw, b / grid.bw);
            bx == 0 || by == 0 || bx + 1 == grid.bw || by + 1 == grid.bh
        })
        .map(|&b| f64::from(grid.smooth[b]))
        .fold(0.0, f64::max);
    let clipped = at_border > CLIPPED_SHARE * smooth_peak;
    let saturated_pixels = blocks
        .iter()
        .flat_map(|&b| block_pixels(b, grid))
        .filter(|&i| picture.saturated()[i])
        .count();
    let beam = Beam {
        centre: footprint.centre,
        uncertainty: (covariance[0][0] + covariance[1][1]).sqrt(),
        covariance,
        radii: footprint.radii,
        angle_deg: footprint.angle.to_degrees(),
        signal,
        peak,
        saturated: saturated_pixels >= SATURATED_PIXELS,
        clipped,
        edge_level: (at_border / smooth_peak.max(1e-9)).clamp(0.0, 1.0),
        localised: roughness(grid, blocks, peak) < MAX_SPOT_ROUGHNESS,
        parts,
        fit: None,
    };
    let fit = clipped.then(|| fit_gaussian(grid, blocks, &beam)).flatten();
    Some(Beam { fit, ..beam })
}

/// A faint beam's footprint from its averaged blocks (its pixels' moments would be mostly noise).
fn faint_footprint(grid: &Grid, blocks: &[usize]) -> Option<Footprint> {
    let [s, sx, sy] = grid.weighted(blocks, |b| f64::from(grid.smooth[b]));
    let width = ((2 * grid.reach + 1) * BLOCK) as f64;
    let mut fitter = GaussianFitter::new([sx / s, sy / s], width);
    for &b in blocks {
        fitter.add(grid.centre_of(b), f64::from(grid.smooth[b]));
    }
    let fit = fitter.finish(0.0)?;
    // A box `L` wide adds `L²/12` to each axis's variance, `L²/3` to the squared 1/e² radius.
    let radius = (fit.radius.powi(2) - width * width / 3.0)
        .max(0.0)
        .sqrt()
        .max(BLOCK as f64);
    let half = MOMENT_WINDOW_RADII * radius;
    // A square window of side 2 half: each axis's Σ d² is half²/3 per pixel.
    let axis = (2.0 * half).powi(2) * half * half / 3.0;
    Some(Footprint {
        centre: fit.centre,
        radii: [radius, radius],
        angle: 0.0,
        signal: fit.peak * std::f64::consts::PI * fit.radius.powi(2) / 2.0,
        split: None,
        spread: [[axis, 0.0], [0.0, axis]],
    })
}

/// Where a beam is, how large and how bright, and the spread of its measuring window.
struct Footprint {
    centre: [f64; 2],
    /// 1/e² radii along the principal axes (major, minor), px.
    radii: [f64; 2],
    /// Direction of the major axis, radians from +x towards +y.
    angle: f64,
    signal: f64,
    /// Σ dx², Σ dx dy, Σ dy² over the window's pixels, for the centre's covariance.
    spread: [[f64; 2]; 2],
    /// The centre's covariance from [`split_covariance`], px², where measured.
    split: Option<[[f64; 2]; 2]>,
}

/// The footprint of beam `id` from its pixels' moments in a window iterated until it settles.
fn window_footprint(grid: &Grid, owner: &[u32], id: u32, blocks: &[usize]) -> Option<Footprint> {
    let (mut centre, [vxx, vyy, _]) = block_moments(grid, blocks)?;
    let half_for = |v: f64| MOMENT_WINDOW_RADII * (2.0 * v.sqrt()).max(BLOCK as f64);
    let mut half = [vxx, vyy].map(half_for);
    let window = |centre, half| Window {
        grid,
        owner,
        id,
        centre,
        half,
    };
    let moments = |centre: [f64; 2], half: [f64; 2]| {
        let m = window_moments(&window(centre, half));
        if m.s <= 0.0 {
            return None;
        }
        let mean = [m.sx / m.s, m.sy / m.s];
        let cxx = m.sxx / m.s - mean[0].powi(2);
        let cyy = m.syy / m.s - mean[1].powi(2);
        Some((m, mean, [cxx, cyy]))
    };
    for _ in 0..20 {
        let (_, shift, var) = moments(centre, half)?;
        centre = [centre[0] + shift[0], centre[1] + shift[1]];
        half = var.map(|v| half_for(v.max(MIN_MOMENT_VARIANCE_PX2)));
        if shift[0].hypot(shift[1]) < SETTLED_PX {
            break;
        }
    }
    let (m, mean, [cxx, cyy]) = moments(centre, half)?;
    let centre = [centre[0] + mean[0], centre[1] + mean[1]];
    let cxy = m.sxy / m.s - mean[0] * mean[1];
    let gxy = m.gxy - m.n * mean[0] * mean[1];
    // Light only adds: without positive variance in every direction it is noise, not a beam.
    if cxx <= 0.0 || cyy <= 0.0 || cxx * cyy <= cxy * cxy {
        return None;
    }
    let (mid, diff) = ((cxx + cyy) / 2.0, ((cxx - cyy) / 2.0).hypot(cxy));
    let (major, minor) = (mid + diff, (mid - diff).max(0.0));
    let angle = 0.5 * (2.0 * cxy).atan2(cxx - cyy);
    let cell = (2.0 * minor.sqrt() / SPLIT_CELLS_PER_RADIUS)
        .round()
        .max(1.0) as usize;
    Some(Footprint {
        centre,
        radii: [2.0 * major.sqrt(), 2.0 * minor.sqrt()],
        angle,
        signal: m.s,
        split: split_covariance(&window(centre, half), cell),
        // About the centroid rather than the window's centre.
        spread: [
            [m.gxx - m.n * mean[0].powi(2), gxy],
            [gxy, m.gyy - m.n * mean[1].powi(2)],
        ],
    })
}

/// `read` widened by the excess of the samples' covariance `split` (kept positive semi-definite).
fn with_texture(read: [[f64; 2]; 2], split: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let xx = (split[0][0] - read[0][0]).max(0.0);
    let yy = (split[1][1] - read[1][1]).max(0.0);
    let limit = (xx * yy).sqrt();
    let xy = (split[0][1] - read[0][1]).clamp(-limit, limit);
    [
        [read[0][0] + xx, read[0][1] + xy],
        [read[1][0] + xy, read[1][1] + yy],
    ]
}

fn block_pixels(block: usize, grid: &Grid) -> impl Iterator<Item = usize> {
    let (w, h) = (grid.picture.width(), grid.picture.height());
    let (x0, y0) = ((block % grid.bw) * BLOCK, (block / grid.bw) * BLOCK);
    (y0..(y0 + BLOCK).min(h)).flat_map(move |y| (x0..(x0 + BLOCK).min(w)).map(move |x| y * w + x))
}

/// Mean horizontal neighbour difference beyond the noise, over the mean light, on bright blocks.
fn roughness(grid: &Grid, blocks: &[usize], peak: f64) -> f64 {
    let picture = grid.picture;
    let (w, light) = (picture.width(), picture.light());
    let (differences, total, n) = blocks
        .iter()
        .filter(|&&b| f64::from(grid.means[b]) >= f64::from(CORE_SHARE) * peak)
        .flat_map(|&b| block_pixels(b, grid))
        .filter(|&i| i % w + 1 < w && !picture.saturated()[i] && !picture.saturated()[i + 1])
        .fold((0.0, 0.0, 0.0), |(d, t, n), i| {
            (
                d + f64::from((light[i + 1] - light[i]).abs()),
                t + f64::from(light[i]),
                n + 1.0,
            )
        });
    if n == 0.0 || total <= 0.0 {
        return 0.0;
    }
    // Two independent noises differ by 2σ/√π on average.
    let expected = 2.0 * picture.noise() / std::f64::consts::PI.sqrt();
    ((differences / n - expected).max(0.0)) / (total / n)
}

/// A Gaussian fitted to the unsaturated block means (16 pixels each: a fourth of the noise).
fn fit_gaussian(grid: &Grid, blocks: &[usize], beam: &Beam) -> Option<GaussianFit> {
    let block_noise = grid.picture.noise() / BLOCK as f64;
    let floor = (FIT_FLOOR_NOISES * block_noise).max(FIT_FLOOR_SHARE * beam.peak);
    let mut fitter = GaussianFitter::new(beam.centre, beam.size());
    for &b in blocks {
        let mean = f64::from(grid.means[b]);
        if mean <= floor || block_pixels(b, grid).any(|i| grid.picture.saturated()[i]) {
            continue;
        }
        fitter.add(grid.centre_of(b), mean);
    }
    fitter
        .finish(block_noise)
        .filter(|f| f.radius < MAX_FIT_RADIUS_SHARE * beam.size().max(1.0))
}
