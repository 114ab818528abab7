//! Every threshold and size the detector uses, with its unit and the reason for its value. Units:
//! px, gray levels (of an 8-bit frame), noises (read-noise deviations), shares (of a named whole).

// A frame's background, read noise, streaks and hot pixels (`picture`)

/// Cells per short image side for the background fit ...
pub(crate) const CELLS_PER_SIDE: usize = 16;

/// ... each at least this many px across, so its level (64 sampled pixels) stands above the noise.
pub(crate) const MIN_CELL_PX: usize = 16;

/// A cell whose median is this many robust deviations from the plane holds light.
pub(crate) const CELL_OUTLIER: f64 = 3.0;

/// A second background fit starts from this share of the cells, the darkest ...
pub(crate) const DARKEST_START_SHARE: f64 = 0.25;

/// ... rejects and readmits cells for at most this many rounds ...
pub(crate) const FIT_ROUNDS: usize = 20;

/// ... and is the background when this many gray levels below the all-cells fit (light only adds).
pub(crate) const LIFTED_LEVELS: f64 = 1.0;

/// The cells' scatter about the background is a misfit only above this many times their noise.
pub(crate) const MISFIT_SIGNIFICANCE: f64 = 1.5;

/// A quadratic background replaces the plane when its misfit is at most this share of the plane's.
pub(crate) const QUADRATIC_GAIN: f64 = 0.5;

/// Share of the image height at the top and at the bottom where column streaks are read.
pub(crate) const BAND_SHARE: f64 = 0.08;

/// A column offset smaller than this many standard errors of its estimate is noise.
pub(crate) const STREAK_SIGNIFICANCE: f64 = 5.0;

/// Columns averaged for a faint, wide streak.
pub(crate) const STREAK_COLUMNS: usize = 9;

/// A hot pixel exceeds the background by this many noise deviations ...
pub(crate) const HOT_NOISES: f64 = 6.0;

/// ... and all but one of its eight neighbours by this factor.
pub(crate) const HOT_RATIO: f32 = 2.5;

/// The floor of the noise estimate, quantisation steps (quantisation alone gives 0.29).
pub(crate) const MIN_NOISE_STEPS: f64 = 0.3;

/// Histogram bins at most: a 16-bit frame's are then 1/16 gray level, finer than any read noise.
pub(crate) const MAX_BINS: u32 = 4096;

/// Above this share of background at 0, noise is read above black (clipping shrinks differences).
pub(crate) const CLIPPED_DARK_SHARE: f64 = 0.02;

/// Above this share of a cell's pixels at 0, its level is read above black (below: mean ±0.05 σ).
pub(crate) const CELL_CLIPPED_SHARE: f64 = 0.1;

/// Below this share of cells with a level (others read nearly all black), the others are set to 0.
pub(crate) const MIN_KNOWN_SHARE: f64 = 0.3;

/// How far above the share of clipped pixels a quantile used for the noise must lie.
pub(crate) const CLIP_MARGIN: f64 = 0.05;

/// A top value on this many pixels, more than on the value below, is saturation below full scale.
pub(crate) const SATURATION_PLATEAU_PIXELS: usize = 8;

/// Rounds of rejecting and readmitting cells in the plane fit.
pub(crate) const PLANE_ROUNDS: usize = 5;

/// A quadratic background (six terms) needs at least this many kept cells: two per term.
pub(crate) const MIN_QUADRATIC_CELLS: usize = 12;

/// Histogram values this many robust deviations above the median are light, not background.
pub(crate) const HISTOGRAM_OUTLIER_SPREADS: f64 = 8.0;

/// Share of a histogram's values its trimmed mean keeps (the brightest 2 % are light or hot).
pub(crate) const TRIMMED_KEEP_SHARE: f64 = 0.98;

// The noise map (`noise`)

/// Side of the map's cells, px.
pub(crate) const NOISE_CELL: usize = 8;

/// A cell's level is the mean over this many cells either side of it too.
pub(crate) const LEVEL_REACH: usize = 1;

// Finding and measuring beams (`beams`)

/// Pixels per side of the blocks the picture is reduced to for finding regions.
pub(crate) const BLOCK: usize = 4;

/// A smoothed block holds light above this many noise deviations of its average.
pub(crate) const THRESHOLD_NOISES: f64 = 4.5;

/// Regions whose light is below this share of the strongest region's are dropped.
pub(crate) const MIN_SHARE: f64 = 0.002;

/// A region's light must exceed the noise summed over its pixels this many times.
pub(crate) const MIN_SIGNIFICANCE: f64 = 8.0;

/// Blocks above this share of a region's peak are its core.
pub(crate) const CORE_SHARE: f32 = 0.2;

/// Smoothed-block noises a split region's core must peak above the core level (not a noise island).
pub(crate) const CORE_PROMINENCE_NOISES: f32 = 5.0;

/// Regions are one beam if their cores are nearer than this share of their distance (a node is
/// narrow, a gap between beams wide) ...
pub(crate) const JOIN_GAP_SHARE: f64 = 0.35;

/// ... and the weaker peak is at least this share of the stronger ...
pub(crate) const JOIN_PEAK_SHARE: f32 = 0.2;

/// ... and the light between them is below this share of two Gaussian tails' sum (a node): half,
/// as moments cut where regions meet underrate the tails; a mode's node holds a few per cent.
pub(crate) const JOIN_NODE_SHARE: f64 = 0.5;

/// The node may exceed that share by this many deviations of a block's mean.
pub(crate) const JOIN_VALLEY_NOISES: f64 = 3.0;

/// Window blocks within this many background misfits are dark: residue would outweigh the wings.
pub(crate) const MOMENT_FLOOR_MISFITS: f32 = 3.0;

/// Half the side of the measuring window (ISO 11146), second-moment (1/e²) radii.
pub(crate) const MOMENT_WINDOW_RADII: f64 = 2.5;

/// The window iteration stops when the centre moves less than this, px.
pub(crate) const SETTLED_PX: f64 = 0.01;

/// Mean neighbour difference beyond the noise, share of the mean light, above which it is speckle.
pub(crate) const MAX_SPOT_ROUGHNESS: f64 = 0.15;

/// A beam still this bright at the image border (share of its peak) is cut by it.
pub(crate) const CLIPPED_SHARE: f64 = 0.05;

/// This many saturated pixels make a saturated beam.
pub(crate) const SATURATED_PIXELS: usize = 4;

/// The spot fit uses blocks brighter than this share of the peak ...
pub(crate) const FIT_FLOOR_SHARE: f64 = 0.08;

/// ... and this many block-noise deviations: the faint rim carries mostly noise.
pub(crate) const FIT_FLOOR_NOISES: f64 = 3.0;

/// A fitted radius beyond this multiple of the measured radius is a flat clump of noise.
pub(crate) const MAX_FIT_RADIUS_SHARE: f64 = 3.0;

/// A region needs at least this many bright blocks (48 px²): fewer are a noise peak.
pub(crate) const MIN_REGION_BLOCKS: usize = 3;

/// Floor of a beam's second moment per axis, px² (a pixel's width): a 1 px spot keeps a window.
pub(crate) const MIN_MOMENT_VARIANCE_PX2: f64 = 0.25;

/// A Gaussian fit needs at least this many points (four unknowns, four times over).
pub(crate) const MIN_GAUSSIAN_PIXELS: usize = 16;

/// Interleaved cell classes (3 x 3) whose scatter gives a centre's certainty: 8 dof per axis.
pub(crate) const SPLIT_CLASSES: usize = 9;

/// Cells of that pattern per minor radius: a 3/4-radius period, where a Gaussian has no power left.
pub(crate) const SPLIT_CELLS_PER_RADIUS: f64 = 4.0;

// A beam's bright core (`core`)

/// Recentring passes: the core window follows the core's own centroid.
pub(crate) const CORE_PASSES: usize = 3;

/// Half the side of the window searched, in beam radii.
pub(crate) const CORE_WINDOW_RADII: f64 = 1.5;

// What changed between two frames (`changes`)

/// Two backgrounds are compared every this many px of a row (smooth: interpolated between).
pub(crate) const BACKGROUND_STRIDE: usize = 16;

/// Pixels brighter than this many noise deviations in both pictures set the gain ...
pub(crate) const GAIN_NOISES: f32 = 10.0;

/// ... when there are at least this many of them.
pub(crate) const GAIN_MIN_PIXELS: usize = 400;

/// Every this-many-th pixel is sampled for the gain.
pub(crate) const GAIN_STRIDE: usize = 3;

/// Side of the cells whose mean changes the level of a difference is fitted to, px.
pub(crate) const LEVEL_CELL: usize = 64;

/// A cell this many robust deviations off the fitted level holds a change of its own.
pub(crate) const LEVEL_OUTLIER: f64 = 3.0;

/// Side of the blocks that decide which sign of change a place shows.
pub(crate) const SIDE_BLOCK: usize = 8;

/// A block whose mean change clearly has the other sign holds the opposite blob.
pub(crate) const SIDE_NOISES: f64 = 3.0;

// The stationary scene's shift (`register`)

/// The window compared spans this many beam radii either side of the core centre.
pub(crate) const SHIFT_WINDOW_RADII: f64 = 1.5;

/// Every this-many-th pixel of the window (per axis) is compared.
pub(crate) const SHIFT_STRIDE: usize = 2;

// A place's backdrop (`backdrop`)

/// Side of the cells, px, over which the darker of the two frames is chosen.
pub(crate) const BACKDROP_CELL: usize = 8;
