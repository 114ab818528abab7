//! Driving a spot to a target with a two-axis relative actuator whose response is not
//! known: a trust-region servo. Two probes from the best tilt so far (one per axis) give
//! the response, then Newton steps from the best tilt, no longer than a trust radius that
//! grows after a step that brought the spot closer and shrinks after one that did not
//! (the next step starts from the best tilt again), refined on whole spots by the bench
//! model (`bench`), whose prior is the probed response. When the sensor's edge cuts the spot, what shows of it moves the right way but
//! less than the beam across the edge: the response is then taken as the rotation (or
//! mirror image) that best fits the two probes, at the larger of their scales, because a
//! mount's two tilt axes deflect the beam at right angles. A response that was not measured
//! on whole spots here (a cut spot's fit, or one assumed beforehand, such as another
//! mirror's) is used until a step between whole spots lands where it predicted; a step
//! that loses the spot or does no good sends the servo back to probing, with probes sized
//! from the response that failed. A probe that lost the
//! spot is tried the other way, then shorter; one that hardly moved it, longer; a response
//! from a cut spot that proved wrong is probed again with longer probes, which show more
//! than the ones that misled it; a response refuted again from the same best tilt is
//! probed the other way round from the last.

use nalgebra::Matrix2;

use super::bench::Response;
use super::model::{Affine, Vec2, carried, column_norm, distance};
use super::tuning::{GAIN_PRIOR_SHARE, MIN_NOISE_PX, PRIOR_OFFSET_PX};

/// A cut spot counts as this many image shorter sides farther than any whole one, less
/// the share of a whole spot's light it shows.
const CUT_PENALTY_SIDES: f64 = 1.0;

/// A probe that moved the spot less than this share of the image's shorter side is grown.
const MIN_MOVE_SHARE: f64 = 0.03;

/// Growth (and shrinking) of probes and of the trust radius.
const GROWTH: f64 = 2.0;

/// A probe sized from a response aims to move the spot this share of the image's shorter
/// side.
const PROBE_VIEW_SHARE: f64 = 0.15;

/// The trust radius starts at this many probe lengths.
const START_RADIUS_PROBES: f64 = 4.0;

/// An assumed response is confirmed by a step between whole spots that lands within this
/// share of the predicted move from where it predicted.
const CONFIRM_SHARE: f64 = 0.5;

/// How far the response can be trusted.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Trust {
    /// Measured here on whole spots, or given as known.
    Measured,
    /// Fitted to probes of a cut spot: it points the way while the spot is cut.
    Cut,
    /// Not measured here on whole spots (a cut spot's fit once the spot shows whole, or
    /// given as a guess): the next step between whole spots confirms or refutes it.
    Assumed,
}

/// Where the spot showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spot {
    /// Its centre (for a cut spot, its rough place).
    pub at: Vec2,
    /// Whole: not cut by the sensor's edge.
    pub whole: bool,
    /// Its light.
    pub signal: f64,
}

/// The best tilt so far and what it showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Best {
    pub tilt: Vec2,
    pub spot: Spot,
    error: f64,
}

/// What the last command was.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Pending {
    Nothing,
    Probe {
        axis: usize,
        sign: f64,
        flipped: bool,
    },
    Step,
}

/// The servo of one station.
#[derive(Clone, Debug)]
pub struct Servo {
    best: Option<Best>,
    /// The response (px per step, columns per axis), once known.
    gain: Option<[[f64; 2]; 2]>,
    trust: Trust,
    /// Each axis's probed response, and whether a cut spot took part.
    columns: [Option<(Vec2, bool)>; 2],
    probe: f64,
    radius: f64,
    /// Shortest and longest probe or step, steps.
    bounds: Vec2,
    pending: Pending,
    /// The last tilt and spot seen, for the model's updates.
    last: Option<(Vec2, Spot)>,
    /// The bench model refining the response from steps between whole spots, from the
    /// first such step after the response was set.
    belief: Option<Response>,
    /// The most light a spot showed, for how much of a cut one shows.
    brightest: f64,
    /// The way the next round of probes first goes (+1, -1).
    probe_sign: f64,
    /// The best tilt a response was last refuted from.
    refuted_at: Option<Vec2>,
}

impl Servo {
    /// A servo whose probes start at `probe` steps within `bounds`, with a response when
    /// one is known beforehand.
    pub fn new(probe: f64, bounds: Vec2, gain: Option<[[f64; 2]; 2]>) -> Self {
        let probe = probe.clamp(bounds[0], bounds[1]);
        Self {
            best: None,
            gain,
            trust: Trust::Measured,
            columns: [None; 2],
            probe,
            radius: (START_RADIUS_PROBES * probe).clamp(bounds[0], bounds[1]),
            bounds,
            pending: Pending::Nothing,
            last: None,
            belief: None,
            brightest: 0.0,
            probe_sign: 1.0,
            refuted_at: None,
        }
    }

    /// The same servo starting from a guess of the response (another mirror's, say), used
    /// until the first step between whole spots confirms or refutes it.
    pub fn assume(mut self, gain: [[f64; 2]; 2]) -> Self {
        self.gain = Some(gain);
        self.belief = None;
        self.trust = Trust::Assumed;
        self
    }

    pub fn best(&self) -> Option<Best> {
        self.best
    }

    /// How far the tilt really moved since the last sighting, by the measured response,
    /// for a spot now `seen` where it was whole both times, when the tilt was meant to move
    /// from there to `tilt` by enough to show on an image whose shorter side is `side`:
    /// the tilt of that sighting and the move.
    pub fn moved_since_last(&self, tilt: Vec2, seen: &Spot, side: f64) -> Option<(Vec2, Vec2)> {
        let gain = self.gain.filter(|_| self.trust == Trust::Measured)?;
        let (from, was) = self.last.filter(|(_, was)| was.whole && seen.whole)?;
        if distance(carried(gain, from, was.at, tilt), was.at) < MIN_MOVE_SHARE * side {
            return None;
        }
        let response = Affine {
            offset: was.at,
            gain,
        };
        Some((from, response.solve(seen.at)?))
    }

    /// The response, unless it came from a cut spot's probes.
    pub fn gain(&self) -> Option<[[f64; 2]; 2]> {
        self.gain.filter(|_| self.trust != Trust::Cut)
    }

    /// Forgets a response that proved wrong: the next commands probe again from the best
    /// tilt, with probes that would move the spot a useful share of the image at its scale.
    fn forget_gain(&mut self, side: f64) {
        if let Some(gain) = self.gain {
            self.probe = useful_probe(side, column_norm(gain).max(1e-9))
                .clamp(self.bounds[0], self.bounds[1]);
        }
        self.drop_gain();
    }

    /// Drops the response: the next commands probe both axes again from the best tilt.
    fn drop_gain(&mut self) {
        self.gain = None;
        self.belief = None;
        self.trust = Trust::Measured;
        self.columns = [None; 2];
        self.pending = Pending::Nothing;
    }

    /// How far a spot is from `target`, as the servo ranks them: a whole spot by its
    /// distance; a cut one behind every whole one, by how little of it shows.
    fn error(&self, spot: &Spot, target: Vec2, side: f64) -> f64 {
        if spot.whole {
            distance(spot.at, target)
        } else {
            let shows = (spot.signal / self.brightest.max(1e-9)).min(1.0);
            CUT_PENALTY_SIDES * side * (2.0 - shows)
        }
    }

    /// Learns from what the last command showed at `tilt` (`seen`: where the spot is, if it
    /// shows), for `target` on an image whose shorter side is `side`.
    pub fn observe(&mut self, tilt: Vec2, seen: Option<Spot>, target: Vec2, side: f64) {
        if let Some(s) = seen {
            self.brightest = self.brightest.max(s.signal);
        }
        if let Some(best) = self.best {
            // The yardstick of cut spots may have grown since.
            let error = self.error(&best.spot, target, side);
            self.best = Some(Best { error, ..best });
        }
        match (self.pending, seen, self.best) {
            (
                Pending::Probe {
                    axis,
                    sign,
                    flipped,
                },
                None,
                _,
            ) => {
                // Lost: the other way, then shorter.
                self.pending = Pending::Probe {
                    axis,
                    sign: -sign,
                    flipped: true,
                };
                if flipped {
                    self.probe = (self.probe / GROWTH).max(self.bounds[0]);
                }
                return;
            }
            (Pending::Probe { axis, .. }, Some(s), Some(best)) => {
                let du = tilt[axis] - best.tilt[axis];
                if distance(s.at, best.spot.at) < MIN_MOVE_SHARE * side {
                    self.probe = (self.probe * GROWTH).min(self.bounds[1]);
                } else if du.abs() > 0.5 {
                    let column = [
                        (s.at[0] - best.spot.at[0]) / du,
                        (s.at[1] - best.spot.at[1]) / du,
                    ];
                    self.columns[axis] = Some((column, !(s.whole && best.spot.whole)));
                }
                if let [Some((c0, r0)), Some((c1, r1))] = self.columns
                    && self.gain.is_none()
                {
                    let measured = [[c0[0], c1[0]], [c0[1], c1[1]]];
                    let cut = r0 || r1;
                    self.trust = if cut { Trust::Cut } else { Trust::Measured };
                    self.gain = Some(if cut {
                        rotation_fit(measured)
                    } else {
                        measured
                    });
                }
            }
            _ => {}
        }
        let better = match (error(self, seen, target, side), self.best) {
            (Some(e), Some(best)) => e < best.error,
            (Some(_), None) => true,
            (None, _) => false,
        };
        if self.pending == Pending::Step {
            self.learn_from_step(tilt, seen, better, side);
        }
        if let (true, Some(spot)) = (better, seen) {
            let error = self.error(&spot, target, side);
            if self.trust == Trust::Cut && spot.whole {
                // Shows whole now: the cut spot's fit serves as a guess that the next step
                // between whole spots confirms or refutes.
                self.trust = Trust::Assumed;
            }
            self.best = Some(Best { tilt, spot, error });
            if self.pending == Pending::Step {
                self.radius = (self.radius * GROWTH).min(self.bounds[1]);
            }
        } else if self.pending == Pending::Step {
            self.radius = (self.radius / GROWTH).max(self.bounds[0]);
        }
        if let Some(s) = seen {
            self.last = Some((tilt, s));
        }
    }

    /// What a step from the last spot seen to `tilt` (where `seen` showed, `better` than
    /// the best before) says of the response: between whole spots it refines it (the bench
    /// model);
    /// an assumed one is confirmed by a step between whole spots that lands where it
    /// predicted, kept on trial by one that missed but still did good, and refuted by one
    /// that lost the spot or did no good.
    fn learn_from_step(&mut self, tilt: Vec2, seen: Option<Spot>, better: bool, side: f64) {
        let Some(gain) = self.gain else {
            return;
        };
        let between_whole = match (self.last, seen) {
            (Some((from, was)), Some(now)) if was.whole && now.whole => Some((from, was, now)),
            _ => None,
        };
        if self.trust == Trust::Assumed {
            let landed_as_predicted = between_whole.is_some_and(|(from, was, now)| {
                let predicted = carried(gain, from, was.at, tilt);
                let moved = distance(predicted, was.at);
                distance(predicted, now.at) < CONFIRM_SHARE * moved
            });
            if landed_as_predicted {
                self.trust = Trust::Measured;
            } else if !(seen.is_some() && better) {
                self.forget_gain(side);
                return;
            }
        }
        // A move too short to show beyond the centroids' noise teaches nothing.
        if let Some((from, was, now)) = between_whole
            && distance(was.at, now.at).max(distance(carried(gain, from, was.at, tilt), was.at))
                >= MIN_MOVE_SHARE * side
        {
            let noise = Matrix2::identity() * MIN_NOISE_PX * MIN_NOISE_PX;
            let belief = self.belief.get_or_insert_with(|| {
                let prior = Affine {
                    offset: was.at,
                    gain,
                }
                .anchored(from, was.at);
                let spread = GAIN_PRIOR_SHARE * column_norm(gain);
                let mut belief = Response::with_prior(from, prior, PRIOR_OFFSET_PX, spread);
                belief.add(from, was.at, noise);
                belief
            });
            belief.add(tilt, now.at, noise);
            if let Some(refined) = belief.mean() {
                self.gain = Some(refined.gain);
            }
        }
    }

    /// The next tilt: a probe of an axis whose response is not known yet, or a Newton step
    /// towards `target` from the best tilt; `None` before the spot was ever seen.
    pub fn next(&mut self, target: Vec2) -> Option<Vec2> {
        let best = self.best?;
        match self.gain {
            None => {
                let axis = usize::from(self.columns[0].is_some());
                let (sign, flipped) = match self.pending {
                    Pending::Probe {
                        axis: a,
                        sign,
                        flipped,
                    } if a == axis => (sign, flipped),
                    _ => (self.probe_sign, false),
                };
                self.pending = Pending::Probe {
                    axis,
                    sign,
                    flipped,
                };
                let mut tilt = best.tilt;
                tilt[axis] += sign * self.probe;
                Some(tilt)
            }
            Some(gain) => {
                let step = Affine {
                    offset: best.spot.at,
                    gain,
                }
                .solve(target)?;
                let length = step[0].hypot(step[1]);
                let scale = (self.radius / length.max(1e-9)).min(1.0);
                let proposal = [
                    best.tilt[0] + step[0] * scale,
                    best.tilt[1] + step[1] * scale,
                ];
                // The tilt just looked at, to within a step, where the caller found the spot
                // off the target: the response cannot get it any closer.
                let standing_still = self.last.is_some_and(|(tilt, _)| {
                    (tilt[0] - proposal[0]).abs() < 1.0 && (tilt[1] - proposal[1]).abs() < 1.0
                });
                if (length < self.bounds[0] && !best.spot.whole) || standing_still {
                    // A spot the response says is where it should be, when it is cut or was
                    // just seen off the target: the response is wrong. Probe again from the
                    // best tilt, longer from a cut spot (they show more of it); refuted from
                    // the same best tilt again, not with the probes that gave it twice
                    // (they would give it for ever), but the other way round.
                    self.drop_gain();
                    if self
                        .refuted_at
                        .is_some_and(|at| distance(at, best.tilt) < 1.0)
                    {
                        self.probe_sign = -self.probe_sign;
                    }
                    self.refuted_at = Some(best.tilt);
                    if !best.spot.whole {
                        self.probe = (self.probe * GROWTH).min(self.bounds[1]);
                    }
                    return self.next(target);
                }
                self.pending = Pending::Step;
                Some(proposal)
            }
        }
    }
}

/// The probe, steps, that moves a spot a useful share of an image whose shorter side is
/// `side` px at a response of `response` px per step.
pub fn useful_probe(side: f64, response: f64) -> f64 {
    PROBE_VIEW_SHARE * side / response
}

/// The servo's ranking of what was seen (`None` when nothing was).
fn error(servo: &Servo, seen: Option<Spot>, target: Vec2, side: f64) -> Option<f64> {
    seen.map(|s| servo.error(&s, target, side))
}

/// The rotation or mirror image, scaled, nearest to a measured response (columns per
/// axis): the two tilt axes of a mount deflect the beam at right angles by about the same
/// amount, so what the probes of a cut spot show (the right way, foreshortened across the
/// edge) fixes the orientation, and the less foreshortened probe the scale.
fn rotation_fit(measured: [[f64; 2]; 2]) -> [[f64; 2]; 2] {
    let m = Matrix2::new(
        measured[0][0],
        measured[0][1],
        measured[1][0],
        measured[1][1],
    );
    let svd = m.svd(true, true);
    let (Some(u), Some(v_t)) = (svd.u, svd.v_t) else {
        return measured;
    };
    let scale = svd.singular_values.max();
    let q = u * v_t * scale;
    [[q[(0, 0)], q[(0, 1)]], [q[(1, 0)], q[(1, 1)]]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A station whose spot sits at `offset + gain · tilt`, on a 640 x 480 sensor; beyond
    /// its border the spot is lost, within 100 px of it cut.
    struct Bench {
        offset: Vec2,
        gain: [[f64; 2]; 2],
    }

    impl Bench {
        fn spot(&self, tilt: Vec2) -> Option<Spot> {
            let at = Affine {
                offset: self.offset,
                gain: self.gain,
            }
            .predict(tilt);
            let inside = at[0].min(640.0 - at[0]).min(at[1]).min(480.0 - at[1]);
            // What shows of a cut spot: less the farther out it is.
            (inside > -60.0).then_some(Spot {
                at,
                whole: inside > 100.0,
                signal: (inside + 60.0).min(160.0),
            })
        }
    }

    fn run(bench: &Bench, probe: f64) -> (usize, Vec2) {
        run_servo(bench, Servo::new(probe, [50.0, 20_000.0], None))
    }

    fn run_servo(bench: &Bench, mut servo: Servo) -> (usize, Vec2) {
        let target = [320.0, 240.0];
        let mut tilt = [0.0, 0.0];
        for step in 1..=30 {
            servo.observe(tilt, bench.spot(tilt), target, 480.0);
            if let Some(best) = servo.best()
                && best.spot.whole
                && distance(best.spot.at, target) < 1.0
            {
                return (step, best.spot.at);
            }
            tilt = servo.next(target).expect("the spot shows at the start");
        }
        panic!("not centred in 30 steps: {:?}", servo.best());
    }

    #[test]
    fn never_asks_again_for_the_tilt_it_just_looked_at() {
        // The beam merged with a stationary stray spot that carries most of the light: the
        // detection moves a fifth as far as the beam and never reaches the target. Commands
        // are whole steps, as on a controller; a proposal within a step of the tilt just
        // seen would be an action that changes nothing, again and again.
        let beam = Affine {
            offset: [560.0, 120.0],
            gain: [[0.03, 0.0], [0.0, 0.03]],
        };
        let stray = [520.0, 110.0];
        let mut servo = Servo::new(1875.0, [50.0, 20_000.0], None);
        let target = [320.0, 240.0];
        let mut tilt = [0.0, 0.0];
        for _ in 0..60 {
            let beam_at = beam.predict(tilt);
            let seen = Some(Spot {
                at: [
                    0.8 * stray[0] + 0.2 * beam_at[0],
                    0.8 * stray[1] + 0.2 * beam_at[1],
                ],
                whole: true,
                signal: 100.0,
            });
            servo.observe(tilt, seen, target, 480.0);
            let Some(next) = servo.next(target) else {
                break;
            };
            let next = next.map(f64::round);
            assert!(
                (next[0] - tilt[0]).abs() >= 1.0 || (next[1] - tilt[1]).abs() >= 1.0,
                "asked for {next:?} again"
            );
            tilt = next;
        }
    }

    #[test]
    fn centres_a_spot_whatever_the_response_turns_and_scales() {
        for gain in [
            [[0.033, 0.0], [0.0, 0.023]],
            [[0.0, -0.03], [0.025, 0.0]],
            [[-0.1, 0.02], [0.03, 0.08]],
            [[0.008, 0.001], [-0.002, -0.006]],
        ] {
            let bench = Bench {
                offset: [150.0, 330.0],
                gain,
            };
            let (steps, at) = run(&bench, 1875.0);
            assert!(steps <= 12, "{gain:?}: {steps} steps, at {at:?}");
        }
    }

    #[test]
    fn a_right_guess_of_the_response_saves_the_probes_and_a_wrong_one_is_dropped() {
        let gain = [[0.0, -0.03], [0.025, 0.0]];
        let bench = Bench {
            offset: [150.0, 330.0],
            gain,
        };
        let servo = || Servo::new(1875.0, [50.0, 20_000.0], None);
        let (probed, _) = run(&bench, 1875.0);
        // Another mirror's response, a fifth off: no probes, so fewer steps.
        let near = gain.map(|row| row.map(|v| 1.2 * v));
        let (guessed, _) = run_servo(&bench, servo().assume(near));
        assert!(
            guessed < probed,
            "{guessed} steps with the guess, {probed} probing"
        );
        // A guess with an axis the wrong way round and one turned a right angle: both are
        // refuted by the spot and the servo probes its way to the centre.
        for wrong in [[[0.0, 0.03], [0.025, 0.0]], [[0.025, 0.0], [0.0, 0.03]]] {
            let (steps, at) = run_servo(&bench, servo().assume(wrong));
            assert!(steps <= probed + 4, "{wrong:?}: {steps} steps, at {at:?}");
        }
    }

    #[test]
    fn a_probe_that_loses_the_spot_is_tried_the_other_way() {
        // The first probe (+axis 0) throws the spot off the sensor's right edge.
        let bench = Bench {
            offset: [560.0, 240.0],
            gain: [[0.05, 0.0], [0.0, 0.05]],
        };
        let (steps, _) = run(&bench, 3000.0);
        assert!(steps <= 12, "{steps}");
    }

    #[test]
    fn a_foreshortened_response_is_fitted_as_a_turned_one() {
        // Turned 30 degrees, scale 0.03; the second axis seen at a third across an edge.
        let (s, c) = 30f64.to_radians().sin_cos();
        let true_gain = [[0.03 * c, -0.03 * s], [0.03 * s, 0.03 * c]];
        let measured = [
            [true_gain[0][0], true_gain[0][1] / 3.0],
            [true_gain[1][0], true_gain[1][1] / 3.0],
        ];
        let fitted = rotation_fit(measured);
        let worst = (0..2)
            .flat_map(|r| (0..2).map(move |c| (r, c)))
            .map(|(r, c)| (fitted[r][c] - true_gain[r][c]).abs())
            .fold(0.0, f64::max);
        assert!(worst < 0.01, "{fitted:?} vs {true_gain:?}");
        // The signs (orientation) are right.
        assert!(fitted[0][0] > 0.0 && fitted[0][1] < 0.0 && fitted[1][1] > 0.0);
    }
}
