//! What the images teach about the bench ([`Scales`]: beam sizes, jitter, centre precision, so
//! every threshold scales with this bench), and whether a beam is a sighting to fit ([`sight`]).

use super::model::{Sighting, Vec2, distance};
use super::see::{View, stationary_pairs};
use super::tuning::{
    CLEAR_OF_BORDER_RADII, DEFAULT_RADIUS_SHARE, DEFAULT_STEADY_RADII, FIT_SIZE_RATIO,
    MAX_EXTRAPOLATION, MAX_MISFIT, MIN_NOISE_PX, OVERLAP_RADII, STEADY_SPREAD,
};
use crate::imaging::{Beam, median};

/// What the images taught about this bench.
#[derive(Clone, Debug, Default)]
pub struct Scales {
    /// Radii of cleanly seen beams per feature, px.
    sizes: [Vec<f64>; 2],
    /// The median radius of the beams in the first view that showed any, px.
    typical: Option<f64>,
    /// The shorter image side, px.
    side: f64,
    /// Displacements of stationary features between frames, px.
    steady: Vec<f64>,
    /// The median centre uncertainty of the latest view's beams, px.
    uncertainty: Option<f64>,
}

/// The radius assumed for a beam not yet measured, px, given the image's shorter `side`.
pub fn default_radius(side: f64) -> f64 {
    DEFAULT_RADIUS_SHARE * side
}

impl Scales {
    /// Learns the image size, the typical beam size and centre uncertainty from a view.
    pub fn learn_view(&mut self, view: &View) {
        self.side = view.shorter_side();
        if self.typical.is_none() {
            self.typical = median(view.beams.iter().map(Beam::size).collect());
        }
        let spreads = view.beams.iter().map(|b| b.uncertainty).collect();
        self.uncertainty = median(spreads).or(self.uncertainty);
    }

    pub fn learn_size(&mut self, k: usize, radius: f64) {
        self.sizes[k].push(radius);
    }

    /// Learns feature `k`'s size from a whole `beam` [`CLEAR_OF_BORDER_RADII`] major radii clear
    /// of every border: beside one, the spot may be one lobe of a beam whose node lies on it.
    pub fn learn_shape(&mut self, k: usize, beam: &Beam, view: &View) {
        let margin = CLEAR_OF_BORDER_RADII * beam.radii[0];
        let size = view.size();
        if (0..2).all(|a| beam.centre[a] >= margin && size[a] - beam.centre[a] >= margin) {
            self.learn_size(k, beam.size());
        }
    }

    /// Pairs the features that stayed between two views and learns the jitter from their moves.
    pub fn learn_steady(&mut self, before: &View, after: &View) -> Vec<(usize, usize)> {
        let pairs = stationary_pairs(&before.beams, &after.beams, self.steady());
        for &(i, j) in &pairs {
            self.steady
                .push(distance(before.beams[i].centre, after.beams[j].centre));
        }
        pairs
    }

    /// Feature `k`'s radius, px: its own, else the other's, the typical beam's, or a default.
    pub fn radius(&self, k: usize) -> f64 {
        self.known_radius(k)
            .or_else(|| self.known_radius(1 - k))
            .or(self.typical)
            .unwrap_or(default_radius(self.side.max(1.0)))
    }

    /// Feature `k`'s radius, px, once it was seen cleanly.
    pub fn known_radius(&self, k: usize) -> Option<f64> {
        median(self.sizes[k].clone())
    }

    /// RMS jitter between frames, px: median displacement / 0.833 (the ratio for 2-D Gaussians).
    fn jitter(&self) -> Option<f64> {
        median(self.steady.clone()).map(|m| m / 0.833)
    }

    /// How far a stationary feature may seem to move between two frames, px.
    pub fn steady(&self) -> f64 {
        match self.jitter() {
            Some(rms) => (STEADY_SPREAD * rms).max(1.0),
            None => DEFAULT_STEADY_RADII * self.radius(0).min(self.radius(1)),
        }
    }

    /// The scatter of one measured centre, px: one frame's jitter (RMS between frames over √2)
    /// combined with the detector's uncertainty, at least [`MIN_NOISE_PX`].
    pub fn model_noise(&self) -> f64 {
        let jitter = self
            .jitter()
            .map_or(0.0, |rms| rms / std::f64::consts::SQRT_2);
        jitter
            .hypot(self.uncertainty.unwrap_or(0.0))
            .max(MIN_NOISE_PX)
    }

    /// What the agent learned about the bench, for the transcript.
    pub fn claims(&self) -> serde_json::Value {
        serde_json::json!({
            "beam_radius_px": [self.known_radius(0), self.known_radius(1)],
            "jitter_rms_px": self.jitter(),
            "steady_allowance_px": self.steady(),
        })
    }
}

/// How `beam`, taken for feature `k`, serves the model: clean when whole, compact and clear of
/// `other` (a known beam's place and radius); a border-cut beam counts when a Gaussian fits well.
pub fn sight(
    beam: &Beam,
    view: &View,
    scales: &Scales,
    k: usize,
    other: Option<(Vec2, f64)>,
) -> Sighting {
    let own = scales.known_radius(k);
    let radius = own.unwrap_or(beam.size());
    let overlapping =
        other.is_some_and(|(p, r)| distance(beam.centre, p) < OVERLAP_RADII * (r + radius));
    if !beam.localised || overlapping {
        return Sighting::Partial(beam.centre);
    }
    if !beam.clipped {
        return Sighting::Clean(beam.centre);
    }
    let [w, h] = view.size();
    let trusted = beam.fit.filter(|f| {
        let outside = |c: f64, side: f64| (-c).max(c - side).max(0.0);
        let beyond = outside(f.centre[0], w).hypot(outside(f.centre[1], h));
        let alike = own.is_none_or(|r| (f.radius / r - 1.0).abs() < FIT_SIZE_RATIO - 1.0);
        // Cut by two borders at once, too little of the spot shows to extrapolate.
        let near = |c: f64, side: f64| c.min(side - c) < f.radius;
        let corner = near(f.centre[0], w) && near(f.centre[1], h);
        f.misfit < MAX_MISFIT && beyond < MAX_EXTRAPOLATION * f.radius && alike && !corner
    });
    trusted.map_or(Sighting::Partial(beam.centre), |fit| {
        Sighting::Fitted(fit.centre)
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::imaging::synthetic::Scene;

    /// A 640 x 480 view of a two-lobed beam (TEM01: lobes above and below `centre`).
    fn two_lobed(centre: [f64; 2]) -> View {
        let frame = Scene::new(640, 480)
            .background(6.0, [0.0, 0.0])
            .hermite_gauss(centre, 60.0, 0, 1, 200.0)
            .noise(2.5, 1)
            .frame();
        View::new(&frame)
    }

    #[test]
    fn a_lobe_whose_node_lies_on_the_border_does_not_teach_the_beam_size() {
        let mut scales = Scales::default();
        // The node on the bottom border: the upper lobe shows whole, nothing is cut.
        let lobe = two_lobed([320.0, 480.0]);
        assert_eq!(lobe.beams.len(), 1, "{:?}", lobe.beams);
        assert!(!lobe.beams[0].clipped, "{:?}", lobe.beams[0]);
        scales.learn_shape(0, &lobe.beams[0], &lobe);
        assert_eq!(scales.known_radius(0), None, "learned from a lobe");
        // Seen whole in the middle, the beam is clean and teaches its size, well above
        // the lobe's.
        let whole = two_lobed([320.0, 240.0]);
        assert_eq!(whole.beams.len(), 1, "{:?}", whole.beams);
        assert!(whole.beams[0].size() > 1.3 * lobe.beams[0].size());
        let seen = sight(&whole.beams[0], &whole, &scales, 0, None);
        assert!(
            matches!(seen, Sighting::Clean(c) if distance(c, [320.0, 240.0]) < 1.0),
            "{seen:?}"
        );
        scales.learn_shape(0, &whole.beams[0], &whole);
        assert_eq!(scales.known_radius(0), Some(whole.beams[0].size()));
    }
}
