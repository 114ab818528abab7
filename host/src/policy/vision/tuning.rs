//! The vision agent's confidence levels, physical limits and every other threshold it uses,
//! each with its unit and the reason for its value. Everything the bench model decides
//! (which sighting to believe, when a map is sure enough to stop) is a probability under the
//! model, set first here; the thresholds of the agents' remaining rules follow, module by
//! module. The detector's own are in `optalign_imaging`'s tuning module.

/// A sighting is set aside when the model gives its innovation (the miss from where the
/// model put it, weighed by the model's and the detector's uncertainty) a chance below
/// 1 - this, probability. At 0.999 a good sighting is set aside once in a thousand (about
/// 3.7 standard deviations in two dimensions), while a merged or foreign beam, tens of
/// deviations off, is not believed.
pub const GATE_CONFIDENCE: f64 = 0.999;

/// The run is done when the model puts the feature within the task's tolerance at the
/// final command with at least this probability. 0.95: the usual level; higher asks for
/// more checks (evaluations) for little gain on benches where a check already lands
/// within the noise.
pub const DONE_CONFIDENCE: f64 = 0.95;

/// Prior standard deviation of where a feature shows for the origin command when nothing
/// is known, px: ten times a large camera's side, so that the first sightings alone decide.
pub const PRIOR_OFFSET_PX: f64 = 1.0e4;

/// Prior standard deviation of each response element when nothing is known, px per step:
/// a hundred times the strongest response of the benches we know (about 0.1 px per step),
/// so that the probes alone decide.
pub const PRIOR_GAIN_PX_PER_STEP: f64 = 10.0;

/// The smallest scatter of one measured centre, px: a centroid on a real camera is rarely
/// better (pixel response non-uniformity, quantisation).
pub const MIN_NOISE_PX: f64 = 0.5;

/// The cavity is aligned when the secondary's centre lies within this share of its own
/// radius of the primary's, px per px: its power overlap with a like mode, exp(-0.4²), is then
/// 85 %, and at the benches' responses that is well within the 500 steps a run is judged
/// by.
pub const CAVITY_TOLERANCE_RADII: f64 = 0.4;

/// A probed response is believed to within this share of its scale per element (prior
/// standard deviation), px per step per px per step: two probes pin each column to a few
/// per cent, but a mount's response changes across its range by more (a lever arm, a
/// spot partly on the sensor's edge), which later steps must be free to correct.
pub const GAIN_PRIOR_SHARE: f64 = 0.5;

// The relay agent (`relay`)

/// The first probe tilts an axis by this share of the cumulative range (both sides).
pub const RELAY_CAUTIOUS_SHARE: f64 = 1.0 / 32.0;

/// Probes and steps stay within these shares of the cumulative range.
pub const RELAY_PROBE_SHARES: [f64; 2] = [1.0 / 512.0, 1.0 / 4.0];

/// While the spot has not been seen at the near station, the search grows by this factor.
pub const SEARCH_GROWTH: f64 = 1.5;

/// ... up to this share of the cumulative range (its grid's first ring then lies half-way
/// to the bound; finer grids follow when the whole range was searched).
pub const MAX_SEARCH_SHARE: f64 = 0.25;

/// With the bench's geometry known, the search grid's points are two probe lengths apart,
/// a probe moving the spot this share of the image's shorter side.
pub const RELAY_SEARCH_GRID_SHARE: f64 = 0.4;

/// A spot at most this bright at the sensor's edge (share of its peak) is whole enough to
/// steer by: its centroid is pulled in by a few pixels, which the next image corrects.
pub const WHOLE_ENOUGH_EDGE: f64 = 0.3;

/// Upstream far stations pass when the spot is within this share of the task's centring
/// tolerance; C8 (done) within the tighter share.
pub const PASS_SHARE: f64 = 0.6;

pub const DONE_SHARE: f64 = 0.4;

/// The near station is centred within this share of the task's centring tolerance (the
/// far station magnifies what is left by the lever ratio).
pub const NEAR_CENTRED_SHARE: f64 = 0.1;

/// A near servo sent to the same load this many times before is going round in a loop.
pub const NEAR_REPEATS: usize = 2;

/// Steps at a far station before going back to the near station to start again.
pub const MAX_FAR_STEPS: usize = 10;

/// A spot not seen at the far station is looked for in views around the expected one, in
/// rings of this many views' widths and heights ...
pub const FAR_SEARCH_RINGS: i32 = 2;

/// ... this share of an image apart, so that neighbouring views overlap.
pub const FAR_SEARCH_OVERLAP: f64 = 0.8;

/// A feature that moved with a tilt is the beam only with at least this share of the
/// strongest feature's light.
pub const MOVED_SHARE: f64 = 0.3;

/// A throw (to learn a station's stationary light) is made only with more evaluations
/// than this left.
pub const MIN_REMAINING_TO_THROW: usize = 10;

/// At most this many throws go one after the other to clear the spot of itself.
pub const MAX_THROWS: usize = 3;

/// A stationary feature is remembered within this many beam radii.
pub const STRAY_RADII: f64 = 0.5;

// The relay's trust-region servo (`servo`)

/// A cut spot counts as this many image shorter sides farther than any whole one, less
/// the share of a whole spot's light it shows.
pub const CUT_PENALTY_SIDES: f64 = 1.0;

/// A probe that moved the spot less than this share of the image's shorter side is grown.
pub const MIN_MOVE_SHARE: f64 = 0.03;

/// Growth (and shrinking) of probes and of the trust radius.
pub const SERVO_GROWTH: f64 = 2.0;

/// A probe sized from a response aims to move the spot this share of the image's shorter
/// side.
pub const SERVO_PROBE_VIEW_SHARE: f64 = 0.15;

/// The trust radius starts at this many probe lengths.
pub const START_RADIUS_PROBES: f64 = 4.0;

// Light that stays put at a camera place (`backdrops`)

/// Another feature counts as light beside the beam with at least this share of its light.
pub const BESIDE_SHARE: f64 = 0.3;

/// A throw moves the beam this many of its radii ...
pub const THROW_RADII: f64 = 4.0;

/// ... and is clear of where it was when its two places in the frames' difference lie at
/// least this many of its radii apart, and the throws made moved it that far by the
/// response (where its tails overlap, a few per cent of its peak stays in the backdrop).
/// Its radius is the largest it shows: in the spot thrown, where it left or where it came
/// (a noisy or speckled spot is seen as fragments smaller than the beam).
pub const CLEAR_RADII: f64 = 2.5;

/// A change in a throw's difference counts with this share of the strongest feature's
/// light (a beam's faint speckle halo included) ...
pub const COME_SHARE: f64 = 0.05;

/// ... unless it lies inside a feature of the picture before with less than this share
/// of its light.
pub const BACKDROPS_RESIDUE_SHARE: f64 = 0.3;

/// A hole with this share of the backdrop's strongest feature's light makes it stale.
pub const HOLE_SHARE: f64 = 0.3;

/// Light this many noise deviations above the backdrop is the frame's own, left out when
/// holes are looked for.
pub const OWN_LIGHT_NOISES: f64 = 3.0;

/// A backdrop holds when taking it off the frame before the throw leaves the beam with
/// this share of its light.
pub const KEPT_SHARE: f64 = 0.3;

// The search for a mount's dead band (`play`)

/// Grid points per search pass.
pub const PLAY_GRID_POINTS: usize = 33;

/// Passes per parameter: the first over its whole range, each later over two cells of
/// the previous grid around its best.
pub const PLAY_PASSES: usize = 4;

/// Rounds over the parameters (each searched with the others held at their best so far).
pub const PLAY_ROUNDS: usize = 3;

/// Local minima of the first grid refined per parameter, the lowest first.
pub const PLAY_REFINED_MINIMA: usize = 3;

// What a move changed (`see`)

/// The beam that moved between a place and the next is the same beam: a detection much
/// larger than its counterpart holds more than the beam (it had merged with another; a
/// detection the border cuts is smaller, so only whole ones compare) ...
pub const MERGED_SIZE: f64 = 1.6;

/// ... as does one with much more light than the change, when the beam moved clear of
/// where it was (or came from or went out of the view).
pub const MERGED_LIGHT: f64 = 1.4;

/// A change within a stationary feature carrying less than this share of its light is
/// residue of the feature's jitter.
pub const SEE_RESIDUE_SHARE: f64 = 0.25;

// Which sighting of a beam is clean (`sight`)

/// Before any beam was measured, a beam is taken to be this share of the image's shorter
/// side (only used until the first view with a beam).
pub const DEFAULT_RADIUS_SHARE: f64 = 0.05;

/// Until jitter has been measured, stationary features may seem to move this many beam
/// radii between frames.
pub const DEFAULT_STEADY_RADII: f64 = 0.15;

/// Stationary features may seem to move this many times their measured RMS displacement.
pub const STEADY_SPREAD: f64 = 4.0;

/// A spot fit worse than this (RMS share of the peak) is two spots merged or not a
/// Gaussian beam: its centre is not extrapolated.
pub const MAX_MISFIT: f64 = 0.1;

/// A fitted centre is trusted up to this many fitted radii outside the image.
pub const MAX_EXTRAPOLATION: f64 = 0.4;

/// A beam larger than this many times its known radius has merged with something.
pub const SIGHT_MAX_SIZE_RATIO: f64 = 1.6;

/// A beam closer than this many summed radii to another known beam overlaps it.
pub const OVERLAP_RADII: f64 = 1.2;

/// A neighbouring detection this many times brighter than a detection at its peak holds
/// the light the detection was split from.
pub const TOUCH_BRIGHTER: f64 = 1.5;

/// A detection still this share of its peak bright at the border is a sliver of light
/// that goes on beyond the image.
pub const SLIVER_EDGE: f64 = 0.5;

/// A beam whose centre lies this many of its major radii from every border shows with
/// dark all round it.
pub const CLEAR_OF_BORDER_RADII: f64 = 2.0;
