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

/// Prior standard deviation of the shift a dead band puts on a feature after a move one
/// way, px, on an axis whose sightings showed one: wider than any band's shift at the
/// benches' responses (300 steps at 0.5 px per step), so that the sightings alone decide.
pub const PRIOR_BAND_PX: f64 = 150.0;

/// The smallest scatter of one measured centre, px: a centroid on a real camera is rarely
/// better (pixel response non-uniformity, quantisation). A command the maps say moves
/// neither beam by this much repeats the frame before, for the jitter.
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

// Probes (every agent)

/// The first probe moves an axis by this share of its command range (the relay: of its
/// cumulative range, both sides), before anything is known of the response: a short first
/// step, grown or shrunk by what it shows.
pub const CAUTIOUS_SHARE: f64 = 1.0 / 32.0;

/// The Michelson's and the cavity's probe lengths stay within these shares of the command
/// range.
pub const PROBE_SHARES: [f64; 2] = [1.0 / 64.0, 1.0 / 3.0];

/// A Michelson or cavity probe that did not move its beam visibly, or too little to
/// resolve, is grown by this factor (three times longer takes any move of more than a
/// third of the needed one past it in one step); a Michelson probe that lost its beam is
/// shrunk by it.
pub const PROBE_GROWTH: f64 = 3.0;

// The relay agent (`relay`)

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

/// Between two frames at one station, a feature that moved less than this many spot radii
/// stayed put. The relay measures no jitter: this is the same idea as
/// [`DEFAULT_STEADY_RADII`] with another factor, kept at the value it was screened with.
pub const RELAY_STEADY_RADII: f64 = 0.1;

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

/// Two detections can be one feature only when their sizes are within this range of
/// ratios ...
pub const ALIKE_SIZE: [f64; 2] = [0.5, 2.0];

/// ... and their light within this one: room for a beam's flicker and texture between
/// frames, while a stray spot or a speck of a different size and brightness is told apart.
/// A beam the border cuts much more in one frame than in the other falls outside them. A
/// Michelson check takes for a beam no detection fainter than the lower share of the most
/// light the beam showed whole (a glow of the background, a stripe beside a fringed beam's
/// centre).
pub const ALIKE_LIGHT: [f64; 2] = [0.33, 3.0];

/// A stationary feature may seem to move by at least this many times the two centres'
/// combined uncertainty (a 3-sigma bound).
pub const STEADY_UNCERTAINTIES: f64 = 3.0;

/// A beam that moved farther than this many of its radii from where it was shows whole in
/// the frames' difference (its old and new places, each about two radii of light across,
/// no longer overlap); a change within that distance of a place belongs to the beam there.
pub const APART_RADII: f64 = 2.0;

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

/// A Gaussian fitted to a spot the border cuts gives its centre only when its radius
/// differs from the beam's known radius by less than this ratio less one (60 %).
pub const FIT_SIZE_RATIO: f64 = 1.6;

/// A beam closer than this many summed radii to another known beam overlaps it.
pub const OVERLAP_RADII: f64 = 1.2;

/// A beam whose centre lies this many of its major radii from every border shows with
/// dark all round it.
pub const CLEAR_OF_BORDER_RADII: f64 = 2.0;

// The Michelson agent (`michelson`)

/// A search grid's points are this share of the image apart in view (a little overlap, so
/// a beam between points shows at least in part).
pub const GRID_VIEW_SHARE: f64 = 0.9;

/// While a beam shows only partly or not at all, probes search in steps of this share of
/// the command range.
pub const MICHELSON_SEARCH_SHARE: f64 = 1.0 / 6.0;

/// A search with a known response moves the beam by this share of the image's shorter
/// side per probe length (the grid's points are two probe lengths apart).
pub const SEARCH_GRID_SHARE: f64 = 0.5;

/// A probe aims to move the beam this many beam radii ...
pub const MICHELSON_PROBE_RADII: f64 = 3.2;

/// ... but at most this share of the image's shorter side.
pub const PROBE_VIEW_SHARE: f64 = 0.37;

/// While one mirror is probed, the other's beam (once its map is known) waits this share
/// of the image width left or right of the centre, on the side away from the probed beam...
pub const PARK_SHARE: f64 = 0.35;

/// ... when it is closer to the centre than this share of the width.
pub const PARK_WHEN_SHARE: f64 = 0.29;

/// The spread of probe commands a fit needs, as a share of the probe length: fitted spot
/// centres are good to a pixel, so a short spread still gives a well-conditioned map.
pub const MIN_SPREAD_SHARE: f64 = 0.125;

/// Half the separation of the two beams at successive checks, in beam radii.
pub const CHECK_APART_RADII: [f64; 3] = [1.8, 2.4, 3.0];

/// A check keeps each beam's centre this many radii inside the image, so that the border
/// cuts neither.
pub const WHOLE_RADII: f64 = 1.5;

/// A check layout puts a beam where wanted when the map lands it within this, px: a pixel,
/// about what a centre is measured to.
pub const LANDS_WITHIN_PX: f64 = 1.0;

/// A beam found farther than this many radii from a beam's prediction is not that beam.
pub const MICHELSON_MATCH_RADII: f64 = 1.0;

/// A probe across a known direction keeps the beam's centre this many radii inside the
/// image, so the beam shows whole.
pub const IN_VIEW_RADII: f64 = 1.0;

/// A partial sighting this many radii from a border was cut by it.
pub const BORDER_RADII: f64 = 0.6;

/// A probed beam is steered to where it stays this many times the two beams' summed
/// radii from the other beam: the detector sees two beams closer than about 1.4 summed
/// radii as one.
pub const MICHELSON_APART_RADII: f64 = 2.0;

/// Directions tried for a probe's target, in steps of this angle either way from straight
/// away from the other beam, radians.
pub const TARGET_TURN: f64 = std::f64::consts::PI / 6.0;

// The cavity agent (`cavity`)

/// The secondary is feature 0 of the learned scales, the primary feature 1.
pub const SECONDARY: usize = 0;

pub const PRIMARY: usize = 1;

/// While the secondary has not been seen, the search steps by this share of the range.
pub const CAVITY_SEARCH_SHARE: f64 = 0.25;

/// After its first rings, the search covers the range on grids this many times finer.
pub const SEARCH_LEVELS: usize = 4;

/// A search point within this share of its grid's spacing of a command already tried looks
/// at what that command showed, and is skipped.
pub const SEARCH_TRIED_SHARE: f64 = 0.25;

/// A probe aims to move the secondary this many of its radii.
pub const CAVITY_PROBE_RADII: f64 = 4.0;

/// A change whose appearing and vanishing parts are closer than this many radii is a beam
/// that moved too little to measure: the probe grows by [`PROBE_GROWTH`].
pub const RESOLVED_RADII: f64 = 2.0;

/// A change whose second-moment radius collapses below this, px, is a speck of a few
/// pixels (a stray spot's flicker, a hot pixel), never a measurable beam.
pub const MIN_CHANGE_RADIUS_PX: f64 = 1.0;

/// Within this many primary radii of the target the secondary is (partly) hidden.
pub const HIDDEN_RADII: f64 = 1.2;

/// The check point sits this many secondary radii outside the hidden zone.
pub const CHECK_CLEARANCE_RADII: f64 = 1.5;

/// The primary's centre is the centroid of its light above this share of its peak, and
/// its core the light above it ...
pub const PRIMARY_CORE_SHARE: f64 = 0.5;

/// ... within this many of its radii.
pub const CORE_REACH_RADII: f64 = 2.0;

/// A change farther than this many radii from the prediction is not the secondary.
pub const CAVITY_MATCH_RADII: f64 = 3.0;

// A mount's map, its lost motion and the search for its feature (`model`)

/// A search that found nothing on one grid goes on with grids this many times finer...
pub const SEARCH_REFINEMENTS: i32 = 4;

/// ... each over this many square rings around the start.
pub const SEARCH_RINGS: i32 = 12;

/// Commands closer than this share of the probe length count as the same probe.
pub const SAME_COMMAND_SHARE: f64 = 0.04;

/// Commands closer than this are the very same command, steps.
pub const SAME_STEP: f64 = 1.0;

/// The spread of clean commands a fit needs, as a share of the shorter probe (the
/// Michelson asks for less: [`MIN_SPREAD_SHARE`]).
pub const MIN_SPREAD_PROBES: f64 = 0.25;

/// A probe of an axis the sightings do not span yet goes one, then two probe lengths
/// either way from the latest clean sighting.
pub const PROBE_MULTIPLES: [f64; 2] = [1.0, 2.0];

/// A probe across a known direction travels along it by at most this many probe lengths
/// (or the span the sightings cover, when longer) ...
pub const ACROSS_REACH_PROBES: f64 = 3.0;

/// ... and goes across by a whole probe when the view has room, else by as much as fits
/// but no less than one over this of a probe; once both signs of that were tried, by that
/// over this again.
pub const ACROSS_SHORTENING: f64 = 3.0;

/// A dead band is looked for on an axis once this many clean sightings were made after it
/// moved ...
pub const BAND_MIN_SIGHTINGS: usize = 8;

/// ... at least this many after moves either way ...
pub const BAND_PER_SIDE: usize = 2;

/// ... and taken when the fit with it explains the misses beyond chance at this
/// confidence (an F test) ...
pub const BAND_CONFIDENCE: f64 = 0.999;

/// ... by more than this many position noises of each sighting's miss (root mean square).
pub const BAND_WORTH_NOISES: f64 = 6.0;

/// A probe aimed by the rough map of every sighting goes at most this many probe lengths
/// per axis ...
pub const ROUGH_REACH: f64 = 3.0;

/// ... and only when the map moves the beam along its weaker direction at least this share
/// as far as along its stronger (a mount's axes respond alike; a map that says one hardly
/// moves the beam was fitted to centroids the border pinned).
pub const ROUGH_BALANCE: f64 = 0.2;

/// A fit keeps at least this many sightings when it sets aside ones the others contradict.
pub const ROBUST_MIN_POINTS: usize = 4;

// The bench model's robust fit (`bench`)

/// The median of the chi-square distribution of two degrees of freedom (2 ln 2).
pub const CHI2_MEDIAN: f64 = 2.0 * std::f64::consts::LN_2;

/// The share of the sightings the core of a robust fit is made of: the subset of this size
/// the model fits best (least trimmed squares), so that a minority of foreign sightings (two
/// beams seen merged, a cut spot) cannot pull it, probability-free.
pub const CORE_SHARE: f64 = 0.6;

/// Subsets for the core are tried exhaustively up to this many sightings, greedily beyond.
pub const CORE_EXHAUSTIVE: usize = 12;

/// Rounds of re-estimating the scatter from the sightings kept (each round keeps at least
/// as many: a few suffice) ...
pub const WIDENING_ROUNDS: usize = 4;

/// ... stopped once it grows by less than this factor.
pub const WIDENING_SETTLED: f64 = 1.05;
