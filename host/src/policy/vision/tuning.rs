//! Every threshold the vision agent uses, with its unit and reason, module by module. The
//! detector's own are in `optalign_imaging`'s tuning module.

/// Probability: sightings beyond this innovation quantile (3.7 sigma in 2-D) are set aside, so a
/// good one is lost once in 1,000 while a merged or foreign beam, tens of sigma off, never passes.
pub const GATE_CONFIDENCE: f64 = 0.999;

/// Probability of landing within tolerance the model needs to declare done: the usual level.
pub const DONE_CONFIDENCE: f64 = 0.95;

/// Prior SD of a feature's place at the origin command, px: 10 camera sides, so sightings decide.
pub const PRIOR_OFFSET_PX: f64 = 1.0e4;

/// Prior SD of a response element, px per step: 100 x the strongest known (0.1); probes decide.
pub const PRIOR_GAIN_PX_PER_STEP: f64 = 10.0;

/// Prior SD of a dead band's shift, px: above any bench's (300 steps at 0.5 px per step).
pub const PRIOR_BAND_PX: f64 = 150.0;

/// Smallest scatter of a measured centre, px (pixel non-uniformity); moves below it repeat a frame.
pub const MIN_NOISE_PX: f64 = 0.5;

/// Aligned: centres within this share of the secondary's radius, px per px (85 % power overlap).
pub const CAVITY_TOLERANCE_RADII: f64 = 0.4;

/// Prior SD of a probed response, share of its scale: a mount's response varies across its range.
pub const GAIN_PRIOR_SHARE: f64 = 0.5;

// Probes (every agent)

/// First probe, share of the command range (relay: cumulative): short, as the response is unknown.
pub const CAUTIOUS_SHARE: f64 = 1.0 / 32.0;

/// Bounds of the Michelson's and the cavity's probe lengths, shares of the command range.
pub const PROBE_SHARES: [f64; 2] = [1.0 / 64.0, 1.0 / 3.0];

/// Factor a too-short probe grows by (3x clears a third of the need at once); a lost one shrinks.
pub const PROBE_GROWTH: f64 = 3.0;

// The relay agent (`relay`)

/// Bounds of probes and steps, shares of the cumulative range.
pub const RELAY_PROBE_SHARES: [f64; 2] = [1.0 / 512.0, 1.0 / 4.0];

/// Growth factor of the near-station search while the spot is unseen ...
pub const SEARCH_GROWTH: f64 = 1.5;

/// ... up to this share of the cumulative range (its first grid ring then reaches half-way out).
pub const MAX_SEARCH_SHARE: f64 = 0.25;

/// A relay search probe moves the spot this share of the shorter image side (grid: 2 probes).
pub const RELAY_SEARCH_GRID_SHARE: f64 = 0.4;

/// Edge light, share of the peak, up to which a spot counts whole: its centroid is a few px off.
pub const WHOLE_ENOUGH_EDGE: f64 = 0.3;

/// Upstream far stations pass with the spot within this share of the centring tolerance ...
pub const PASS_SHARE: f64 = 0.6;

/// ... C8 (done) within this tighter one.
pub const DONE_SHARE: f64 = 0.4;

/// Near-station centring, share of the centring tolerance: the far station magnifies the rest.
pub const NEAR_CENTRED_SHARE: f64 = 0.1;

/// Steps at a far station before going back to the near station to start again.
pub const MAX_FAR_STEPS: usize = 10;

/// A spot unseen at the far station is looked for in this many rings of views around ...
pub const FAR_SEARCH_RINGS: i32 = 2;

/// ... this share of an image apart, so that neighbouring views overlap.
pub const FAR_SEARCH_OVERLAP: f64 = 0.8;

/// A feature that moved with a tilt is the beam only with this share of the strongest's light.
pub const MOVED_SHARE: f64 = 0.3;

/// Spot radii within which a feature stayed put between frames (the relay measures no jitter).
pub const RELAY_STEADY_RADII: f64 = 0.1;

/// A throw (to learn a station's stationary light) needs more evaluations than this left.
pub const MIN_REMAINING_TO_THROW: usize = 10;

/// At most this many throws go one after the other to clear the spot of itself.
pub const MAX_THROWS: usize = 3;

/// A stationary feature is remembered within this many beam radii.
pub const STRAY_RADII: f64 = 0.5;

// The relay's trust-region servo (`servo`)

/// A cut spot ranks this many shorter image sides behind any whole one, less the share it shows.
pub const CUT_PENALTY_SIDES: f64 = 1.0;

/// A probe that moved the spot less than this share of the image's shorter side is grown.
pub const MIN_MOVE_SHARE: f64 = 0.03;

/// Factor by which probes and the trust radius grow or shrink.
pub const SERVO_GROWTH: f64 = 2.0;

/// A probe sized from a response moves the spot this share of the image's shorter side.
pub const SERVO_PROBE_VIEW_SHARE: f64 = 0.15;

/// The trust radius starts at this many probe lengths.
pub const START_RADIUS_PROBES: f64 = 4.0;

// Light that stays put at a camera place (`backdrops`)

/// Another feature counts as light beside the beam with at least this share of its light.
pub const BESIDE_SHARE: f64 = 0.3;

/// A throw moves the beam this many of its radii ...
pub const THROW_RADII: f64 = 4.0;

/// ... and is clear once its two places in the difference, and the response's move, are this many
/// of its largest radii apart (noise fragments a spot); nearer, overlapping tails stay behind.
pub const CLEAR_RADII: f64 = 2.5;

/// A change in a throw's difference counts with this share of the strongest light (halo too) ...
pub const COME_SHARE: f64 = 0.05;

/// ... unless inside a feature of the picture before, with less than this share of its light.
pub const BACKDROPS_RESIDUE_SHARE: f64 = 0.3;

/// A hole with this share of the backdrop's strongest feature's light makes it stale.
pub const HOLE_SHARE: f64 = 0.3;

/// Light this many noise deviations above the backdrop is the frame's own: no hole there.
pub const OWN_LIGHT_NOISES: f64 = 3.0;

/// A backdrop holds if taking it off the frame before the throw leaves this share of the beam.
pub const KEPT_SHARE: f64 = 0.3;

// What a move changed (`see`)

/// A whole detection this many times larger than its counterpart has merged with another ...
pub const MERGED_SIZE: f64 = 1.6;

/// ... as does one this many times the change's light, once the beam moved clear of where it was.
pub const MERGED_LIGHT: f64 = 1.4;

/// A change within a stationary feature with under this share of its light is jitter residue.
pub const SEE_RESIDUE_SHARE: f64 = 0.25;

/// Two detections can be one feature only with sizes within this range of ratios ...
pub const ALIKE_SIZE: [f64; 2] = [0.5, 2.0];

/// ... and light within this one: room for flicker, not for a stray spot or a much more cut beam.
/// A Michelson check takes no detection below the lower share of the beam's brightest whole light.
pub const ALIKE_LIGHT: [f64; 2] = [0.33, 3.0];

/// Stationary features may seem to move at least this many combined centre uncertainties (3 sigma).
pub const STEADY_UNCERTAINTIES: f64 = 3.0;

/// Radii beyond which a moved beam shows whole in the difference; a nearer change is that beam's.
pub const APART_RADII: f64 = 2.0;

// Which sighting of a beam is clean (`sight`)

/// A beam's radius before any was measured, share of the image's shorter side.
pub const DEFAULT_RADIUS_SHARE: f64 = 0.05;

/// Until jitter is measured, stationary features may seem to move this many beam radii.
pub const DEFAULT_STEADY_RADII: f64 = 0.15;

/// Stationary features may seem to move this many times their measured RMS displacement.
pub const STEADY_SPREAD: f64 = 4.0;

/// A spot fit worse than this, RMS share of the peak, is merged or not Gaussian: no extrapolation.
pub const MAX_MISFIT: f64 = 0.1;

/// A fitted centre is trusted up to this many fitted radii outside the image.
pub const MAX_EXTRAPOLATION: f64 = 0.4;

/// A cut spot's fitted centre counts only if the fitted radius is within this ratio of the beam's.
pub const FIT_SIZE_RATIO: f64 = 1.6;

/// A beam closer than this many summed radii to another known beam overlaps it.
pub const OVERLAP_RADII: f64 = 1.2;

/// A beam whose centre is this many major radii from every border shows with dark all round.
pub const CLEAR_OF_BORDER_RADII: f64 = 2.0;

// The Michelson agent (`michelson`)

/// Search grid spacing, share of the image in view: overlapping, so a beam between points shows.
pub const GRID_VIEW_SHARE: f64 = 0.9;

/// Probe step, share of the command range, while a beam shows only partly or not at all.
pub const MICHELSON_SEARCH_SHARE: f64 = 1.0 / 6.0;

/// A mapped search moves the beam this share of the shorter image side per probe (grid: 2 probes).
pub const SEARCH_GRID_SHARE: f64 = 0.5;

/// A probe aims to move the beam this many beam radii ...
pub const MICHELSON_PROBE_RADII: f64 = 3.2;

/// ... but at most this share of the image's shorter side.
pub const PROBE_VIEW_SHARE: f64 = 0.37;

/// A parked beam waits this share of the image width from the centre, away from the probed one ...
pub const PARK_SHARE: f64 = 0.35;

/// ... when it is closer to the centre than this share of the width.
pub const PARK_WHEN_SHARE: f64 = 0.29;

/// Spread of probe commands a fit needs, share of the probe: small, centres being good to 1 px.
pub const MIN_SPREAD_SHARE: f64 = 0.125;

/// Half the separation of the two beams at successive checks, in beam radii.
pub const CHECK_APART_RADII: [f64; 3] = [1.8, 2.4, 3.0];

/// A check keeps each beam's centre this many radii inside the image, clear of the border.
pub const WHOLE_RADII: f64 = 1.5;

/// A check layout lands a beam where wanted within this, px: about what a centre is good to.
pub const LANDS_WITHIN_PX: f64 = 1.0;

/// A beam found farther than this many radii from a beam's prediction is not that beam.
pub const MICHELSON_MATCH_RADII: f64 = 1.0;

/// A probe across a known direction keeps the beam's centre this many radii inside the image.
pub const IN_VIEW_RADII: f64 = 1.0;

/// A partial sighting this many radii from a border was cut by it.
pub const BORDER_RADII: f64 = 0.6;

/// Summed radii a probed beam keeps from the other: the detector merges beams within about 1.4.
pub const MICHELSON_APART_RADII: f64 = 2.0;

/// Step between directions tried for a probe's target, from straight away from the other beam, rad.
pub const TARGET_TURN: f64 = std::f64::consts::PI / 6.0;

// The cavity agent (`cavity`)

/// The secondary is feature 0 of the learned scales, the primary feature 1.
pub const SECONDARY: usize = 0;

pub const PRIMARY: usize = 1;

/// While the secondary has not been seen, the search steps by this share of the range.
pub const CAVITY_SEARCH_SHARE: f64 = 0.25;

/// After its first rings, the search covers the range on grids this many times finer.
pub const SEARCH_LEVELS: usize = 4;

/// A search point within this share of its grid's spacing of a command tried is skipped.
pub const SEARCH_TRIED_SHARE: f64 = 0.25;

/// A probe aims to move the secondary this many of its radii.
pub const CAVITY_PROBE_RADII: f64 = 4.0;

/// A change whose appearing and vanishing parts lie closer than this many radii moved unmeasurably.
pub const RESOLVED_RADII: f64 = 2.0;

/// A change of second-moment radius below this, px, is a speck (stray flicker, hot pixel).
pub const MIN_CHANGE_RADIUS_PX: f64 = 1.0;

/// Within this many primary radii of the target the secondary is (partly) hidden.
pub const HIDDEN_RADII: f64 = 1.2;

/// The check point sits this many secondary radii outside the hidden zone.
pub const CHECK_CLEARANCE_RADII: f64 = 1.5;

/// The primary's centre and core: the centroid of its light above this share of its peak ...
pub const PRIMARY_CORE_SHARE: f64 = 0.5;

/// ... within this many of its radii.
pub const CORE_REACH_RADII: f64 = 2.0;

/// A change farther than this many radii from the prediction is not the secondary.
pub const CAVITY_MATCH_RADII: f64 = 3.0;

// A mount's map, its lost motion and the search for its feature (`model`)

/// A search that found nothing on one grid goes on with grids this many times finer ...
pub const SEARCH_REFINEMENTS: i32 = 4;

/// ... each over this many square rings around the start.
pub const SEARCH_RINGS: i32 = 12;

/// Commands closer than this share of the probe length count as the same probe.
pub const SAME_COMMAND_SHARE: f64 = 0.04;

/// Commands closer than this are the very same command, steps.
pub const SAME_STEP: f64 = 1.0;

/// Clean-command spread a fit needs, share of the shorter probe (Michelson: [`MIN_SPREAD_SHARE`]).
pub const MIN_SPREAD_PROBES: f64 = 0.25;

/// Probes of an axis not yet spanned go these many probe lengths either way of the last clean one.
pub const PROBE_MULTIPLES: [f64; 2] = [1.0, 2.0];

/// Probes across a known direction go along it the longer of this many probes and the span seen ...
pub const ACROSS_REACH_PROBES: f64 = 3.0;

/// ... and across it a whole probe when the view has room, else as much as fits but no less than
/// a probe over this; once both signs of that were tried, over this again.
pub const ACROSS_SHORTENING: f64 = 3.0;

/// A dead band is looked for on an axis after this many clean sightings since it moved ...
pub const BAND_MIN_SIGHTINGS: usize = 8;

/// ... at least this many after moves either way ...
pub const BAND_PER_SIDE: usize = 2;

/// ... and taken when the fit with it explains the misses at this confidence (an F test) ...
pub const BAND_CONFIDENCE: f64 = 0.999;

/// ... by more than this many position noises of each sighting's miss (root mean square).
pub const BAND_WORTH_NOISES: f64 = 6.0;

/// A probe aimed by the rough map of all sightings goes at most this many probes per axis ...
pub const ROUGH_REACH: f64 = 3.0;

/// ... if its weaker direction moves the beam this share of its stronger: a mount's axes are alike.
pub const ROUGH_BALANCE: f64 = 0.2;

/// A fit keeps at least this many sightings when it sets aside ones the others contradict.
pub const ROBUST_MIN_POINTS: usize = 4;

// The bench model's robust fit (`bench`)

/// The median of the chi-square distribution of two degrees of freedom (2 ln 2).
pub const CHI2_MEDIAN: f64 = 2.0 * std::f64::consts::LN_2;

/// Share of sightings in a robust fit's core (least trimmed squares): a foreign few cannot pull it.
pub const CORE_SHARE: f64 = 0.6;

/// Subsets for the core are tried exhaustively up to this many sightings, greedily beyond.
pub const CORE_EXHAUSTIVE: usize = 12;

/// Rounds of re-estimating the scatter from the sightings kept (a few suffice) ...
pub const WIDENING_ROUNDS: usize = 4;

/// ... stopped once it grows by less than this factor.
pub const WIDENING_SETTLED: f64 = 1.05;
