//! The vision agent's confidence levels and physical limits, each with its unit and the
//! reason for its value. Everything the bench model decides (which sighting to believe,
//! when a map is sure enough to stop) is a probability under the model, set here.

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
