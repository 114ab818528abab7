//! A trust-region servo driving a spot to a target with a two-axis relative actuator, over the
//! bench model of the station's response. See docs/vision.md ("Relay", guessed responses).

use super::bench::{Point, Response, STILL, isotropic};
use super::model::{Affine, Vec2, column_norm, distance};
use super::tuning::{
    CUT_PENALTY_SIDES, GAIN_PRIOR_SHARE, MIN_MOVE_SHARE, SAME_STEP, SERVO_GROWTH,
    SERVO_PROBE_VIEW_SHARE, START_RADIUS_PROBES,
};

/// Where the spot showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spot {
    /// Its centre (for a cut spot, its rough place).
    pub at: Vec2,
    /// Whole: not cut by the sensor's edge.
    pub whole: bool,
    pub signal: f64,
    /// The standard deviation of its centre per axis, px.
    pub scatter: f64,
}

/// The best tilt so far and what it showed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Best {
    pub tilt: Vec2,
    pub spot: Spot,
}

/// What the last command was.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Pending {
    #[default]
    Nothing,
    Probe {
        axis: usize,
        sign: f64,
        flipped: bool,
    },
    Step,
}

/// The servo of one station.
#[derive(Clone, Debug, Default)]
pub struct Servo {
    best: Option<Best>,
    /// The bench model of the response, from the first sighting on.
    model: Option<Response>,
    /// The response the model started from (given, or probed on both axes); `None`: not steered.
    prior: Option<[[f64; 2]; 2]>,
    /// A step confirmed the model's response (or it was given as measured).
    confirmed: bool,
    /// Each axis was probed since the model last knew nothing.
    probed: [bool; 2],
    /// A cut spot took part in the probes the response came from.
    cut: bool,
    probe: f64,
    radius: f64,
    /// Shortest and longest probe or step, steps.
    bounds: Vec2,
    pending: Pending,
    /// The last tilt a spot was seen at.
    last: Option<Vec2>,
    /// The most light a spot showed, for how much of a cut one shows.
    brightest: f64,
    /// The way the next round of probes first goes (+1, -1).
    probe_sign: f64,
    /// The best tilt a response was last refuted from.
    refuted_at: Option<Vec2>,
}

impl Servo {
    /// Probes start at `probe` steps within `bounds`; a `gain` known beforehand is confirmed.
    pub fn new(probe: f64, bounds: Vec2, gain: Option<[[f64; 2]; 2]>) -> Self {
        let probe = probe.clamp(bounds[0], bounds[1]);
        Self {
            prior: gain,
            confirmed: true,
            probe,
            radius: (START_RADIUS_PROBES * probe).clamp(bounds[0], bounds[1]),
            bounds,
            probe_sign: 1.0,
            ..Self::default()
        }
    }

    /// Starts from a guessed response (another mirror's, say), if any, until a sighting refutes it.
    pub fn assume(mut self, gain: Option<[[f64; 2]; 2]>) -> Self {
        if gain.is_some() {
            self.prior = gain;
            self.confirmed = false;
        }
        self
    }

    pub fn best(&self) -> Option<Best> {
        self.best
    }

    /// The response steered by (px per step, columns per axis), once known.
    fn steering(&self) -> Option<[[f64; 2]; 2]> {
        match &self.model {
            Some(model) if self.prior.is_some() => model.mean(STILL).map(|m| m.gain),
            _ => self.prior,
        }
    }

    /// The response, unless it came from a cut spot's probes no step confirmed.
    pub fn gain(&self) -> Option<[[f64; 2]; 2]> {
        self.steering().filter(|_| !self.cut)
    }

    /// Drops the response: the model keeps only the best sighting, and both axes are probed again.
    fn drop_gain(&mut self) {
        self.prior = None;
        self.model = self.best.map(|b| model_through(b.tilt, &b.spot, None));
        self.confirmed = true;
        self.probed = [false; 2];
        self.cut = false;
        self.pending = Pending::Nothing;
    }

    /// `x` (a probe or step) longer by [`SERVO_GROWTH`] if `grow`, else shorter, within the bounds.
    fn resized(&self, x: f64, grow: bool) -> f64 {
        if grow {
            (x * SERVO_GROWTH).min(self.bounds[1])
        } else {
            (x / SERVO_GROWTH).max(self.bounds[0])
        }
    }

    /// A spot's error from `target`: a whole one's distance; a cut one ranks behind any whole one.
    fn error(&self, spot: &Spot, target: Vec2, side: f64) -> f64 {
        if spot.whole {
            distance(spot.at, target)
        } else {
            let shows = (spot.signal / self.brightest.max(1e-9)).min(1.0);
            CUT_PENALTY_SIDES * side * (2.0 - shows)
        }
    }

    /// Adds sighting `s` at `tilt` to the model (or starts one) unless refuted; whether it did.
    fn learn(&mut self, tilt: Vec2, s: &Spot) -> bool {
        let r = isotropic(s.scatter);
        let Some(model) = &mut self.model else {
            self.model = Some(model_through(tilt, s, self.prior.map(Affine::linear)));
            return true;
        };
        if self.prior.is_some() && !model.believes(point(tilt, s), r) {
            return false;
        }
        model.add(point(tilt, s), r);
        true
    }

    /// Both axes probed: their response becomes the prior of a model through `s` at `tilt`.
    fn probes_done(&mut self, tilt: Vec2, s: &Spot) {
        let Some(mean) = self.model.as_ref().and_then(|m| m.mean(STILL)) else {
            return;
        };
        self.model = Some(model_through(tilt, s, Some(mean)));
        self.prior = Some(mean.gain);
        self.confirmed = !self.cut;
    }

    /// Learns from what the last command showed at `tilt`; `side` is the image's shorter side, px.
    pub fn observe(&mut self, tilt: Vec2, seen: Option<Spot>, target: Vec2, side: f64) {
        self.brightest = seen.map_or(self.brightest, |s| self.brightest.max(s.signal));
        if let (Pending::Probe { sign, flipped, .. }, None) = (&mut self.pending, seen) {
            // Lost: the other way, then shorter.
            *sign = -*sign;
            if std::mem::replace(flipped, true) {
                self.probe = self.resized(self.probe, false);
            }
            return;
        }
        let believed = seen.is_some_and(|s| self.learn(tilt, &s));
        if let (Pending::Probe { axis, .. }, Some(s), Some(best)) = (self.pending, seen, self.best)
        {
            if distance(s.at, best.spot.at) < MIN_MOVE_SHARE * side {
                self.probe = self.resized(self.probe, true);
            } else if (tilt[axis] - best.tilt[axis]).abs() > 0.5 {
                self.probed[axis] = true;
                self.cut |= !(s.whole && best.spot.whole);
            }
            if self.probed == [true; 2] && self.prior.is_none() {
                self.probes_done(tilt, &s);
            }
        }
        // The best spot ranked afresh: the yardstick of cut spots may have grown since.
        let error = |s: &Spot| self.error(s, target, side);
        let better =
            seen.is_some_and(|s| self.best.is_none_or(|best| error(&s) < error(&best.spot)));
        if self.pending == Pending::Step && !self.confirmed {
            // On trial: a believed whole sighting confirms it; a miss, loss or no gain refutes it.
            match seen {
                Some(s) if believed && s.whole => {
                    self.confirmed = true;
                    self.cut = false;
                }
                Some(_) if believed && better => {}
                _ => {
                    if let Some(gain) = self.steering() {
                        self.probe = useful_probe(side, column_norm(gain).max(1e-9))
                            .clamp(self.bounds[0], self.bounds[1]);
                    }
                    self.drop_gain();
                    if let Some(s) = seen {
                        self.learn(tilt, &s);
                    }
                }
            }
        }
        if self.pending == Pending::Step {
            self.radius = self.resized(self.radius, better);
        }
        if let Some(spot) = seen.filter(|_| better) {
            self.best = Some(Best { tilt, spot });
        }
        self.last = seen.map(|_| tilt).or(self.last);
    }

    /// The next tilt (`None` before any sighting): probe an unknown axis or step towards `target`.
    pub fn next(&mut self, target: Vec2) -> Option<Vec2> {
        let best = self.best?;
        let Some(gain) = self.steering() else {
            let axis = usize::from(self.probed[0]);
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
            return Some(tilt);
        };
        let step = Affine {
            offset: best.spot.at,
            gain,
        }
        .solve(target)?;
        let length = step[0].hypot(step[1]);
        let scale = (self.radius / length.max(1e-9)).min(1.0);
        let proposal = [0, 1].map(|a| best.tilt[a] + step[a] * scale);
        // Back at the tilt just seen off target: the response cannot get any closer.
        let standing_still = self
            .last
            .is_some_and(|tilt| (0..2).all(|a| (tilt[a] - proposal[a]).abs() < SAME_STEP));
        if (length < self.bounds[0] && !best.spot.whole) || standing_still {
            // Wrong response: probe again; refuted here before, the other way (lest it loop).
            self.drop_gain();
            if self
                .refuted_at
                .is_some_and(|at| distance(at, best.tilt) < SAME_STEP)
            {
                self.probe_sign = -self.probe_sign;
            }
            self.refuted_at = Some(best.tilt);
            if !best.spot.whole {
                self.probe = self.resized(self.probe, true);
            }
            return self.next(target);
        }
        self.pending = Pending::Step;
        Some(proposal)
    }
}

/// The probe, steps, moving a spot a useful share of `side` px at `response` px per step.
pub fn useful_probe(side: f64, response: f64) -> f64 {
    SERVO_PROBE_VIEW_SHARE * side / response
}

/// A model through spot `s` at `tilt`, about `prior` (within [`GAIN_PRIOR_SHARE`]) if given.
fn model_through(tilt: Vec2, s: &Spot, prior: Option<Affine>) -> Response {
    let mut model = match prior {
        Some(prior) => {
            let spread = GAIN_PRIOR_SHARE * column_norm(prior.gain);
            Response::with_prior(tilt, prior.anchored(tilt, s.at), spread)
        }
        None => Response::broad(tilt),
    };
    model.add(point(tilt, s), isotropic(s.scatter));
    model
}

/// Spot `s` at `tilt` as a bench-model point, with no dead band (the tracker takes it off).
fn point(tilt: Vec2, s: &Spot) -> Point {
    Point {
        command: tilt,
        dir: STILL,
        image: s.at,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::vision::model::carried;

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
            let whole = inside > 100.0;
            (inside > -60.0).then_some(Spot {
                at,
                whole,
                signal: (inside + 60.0).min(160.0),
                scatter: if whole { 0.5 } else { 60.0 },
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
                scatter: 0.5,
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
        let (guessed, _) = run_servo(&bench, servo().assume(Some(near)));
        assert!(
            guessed < probed,
            "{guessed} steps with the guess, {probed} probing"
        );
        // A guess with an axis the wrong way round and one turned a right angle: both are
        // refuted by the spot and the servo probes its way to the centre.
        for wrong in [[[0.0, 0.03], [0.025, 0.0]], [[0.025, 0.0], [0.0, 0.03]]] {
            let (steps, at) = run_servo(&bench, servo().assume(Some(wrong)));
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
    fn a_sighting_the_model_does_not_believe_is_set_aside() {
        let gain = [[0.03, 0.0], [0.0, 0.03]];
        let target = [320.0, 240.0];
        let spot = |at: Vec2| Spot {
            at,
            whole: true,
            signal: 100.0,
            scatter: 0.5,
        };
        let stepped = |miss: Vec2| {
            let mut servo = Servo::new(1000.0, [50.0, 20_000.0], Some(gain));
            servo.observe([0.0, 0.0], Some(spot([100.0, 100.0])), target, 480.0);
            let tilt = servo.next(target).expect("a step");
            let at = carried(gain, [0.0, 0.0], [100.0, 100.0], tilt);
            let seen = spot([at[0] + miss[0], at[1] + miss[1]]);
            servo.observe(tilt, Some(seen), target, 480.0);
            servo.gain().expect("still known")
        };
        // Where a response a tenth stronger along x puts it: believed, and learned.
        let tilt_x = {
            let mut servo = Servo::new(1000.0, [50.0, 20_000.0], Some(gain));
            servo.observe([0.0, 0.0], Some(spot([100.0, 100.0])), target, 480.0);
            servo.next(target).expect("a step")[0]
        };
        let learned = stepped([0.003 * tilt_x, 0.0]);
        assert!(
            (learned[0][0] - 0.033).abs() < 0.002,
            "{learned:?} after a step of {tilt_x}"
        );
        // Another light 300 px off, taken for the spot: set aside, the response stays.
        let kept = stepped([300.0, 0.0]);
        for (row, want) in kept.iter().zip(gain) {
            for (g, w) in row.iter().zip(want) {
                assert!((g - w).abs() < 1e-9, "{kept:?}");
            }
        }
    }
}
