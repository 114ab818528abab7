//! The relay agent: centres each mirror's spot in turn, at its near station and then at its far
//! one with the response scaled by distance; done when C8 is centred on average over enough
//! camera placements. See docs/vision.md ("Relay").

use nalgebra::{Matrix2, Vector2};
use optalign_optics::{Frame, Station};

use super::backdrops::{Backdrops, Throw, Thrown};
use super::bench::chi2_quantile;
use super::model::{Affine, Tracker, Vec2, carried, column_norm, distance, square_rings};
use super::see::{View, motion, stationary_pairs};
use super::servo::{Servo, Spot, useful_probe};
use super::sight::default_radius;
use super::tuning::{
    CAUTIOUS_SHARE, DONE_CONFIDENCE, DONE_SHARE, FAR_SEARCH_OVERLAP, FAR_SEARCH_RINGS,
    MAX_FAR_STEPS, MAX_SEARCH_SHARE, MAX_THROWS, MIN_NOISE_PX, MIN_REMAINING_TO_THROW, MOVED_SHARE,
    NEAR_CENTRED_SHARE, PASS_SHARE, RELAY_PROBE_SHARES, RELAY_SEARCH_GRID_SHARE,
    RELAY_STEADY_RADII, SAME_STEP, SEARCH_GROWTH, STRAY_RADII, THROW_RADII, WHOLE_ENOUGH_EDGE,
};
use crate::imaging::{Beam, strongest};
use crate::task::{BenchGeometry, RelayAction, RelayLimits};

#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Phase {
    #[default]
    Near,
    Far,
}

/// The relay state machine.
#[derive(Default)]
pub struct RelayAgent {
    limits: RelayLimits,
    /// Each station's distance from the mirror that starts its segment, when known.
    distances: Option<[f64; 8]>,
    /// The camera mover's repeatability, px per axis, when the bench's geometry gives it.
    placement_px: Option<f64>,
    /// C8's placements: the tilt and where the spot showed whole, latest per placement.
    placements: Vec<(Vec2, Vec2)>,
    /// The camera was moved to its station since the last whole spot was booked there.
    placed: bool,
    image_side_px: Option<f64>,
    /// The spot's travel per step at 1 mm from the mirror, px, when the geometry gives it.
    px_per_step_mm: Option<f64>,
    cumulative: [i32; 8],
    station: usize,
    mirror: usize,
    phase: Phase,
    search: Tracker,
    /// The current mirror's tilt when its alignment began (the centre of any search).
    near_start: Vec2,
    near: Servo,
    far: Servo,
    far_steps: usize,
    far_dark: usize,
    /// The mirror's tilt when the camera went to the far station (the centre of a search there).
    far_start: Vec2,
    /// The latest near response measured (px per step) and its station: the next mirror's guess.
    known_near: Option<([[f64; 2]; 2], usize)>,
    /// The last frame, the station it was taken at and the tilts then.
    previous: Option<(View, usize, [i32; 8])>,
    /// Stationary features seen per station (stray light), px.
    stray: Vec<(usize, Vec2)>,
    /// Radius of a whole spot, px, once seen.
    radius: Option<f64>,
    last: Option<RelayAction>,
    /// The spot in the last frame, px.
    seen_at: Option<Vec2>,
    backdrops: Backdrops,
    /// The throw whose frame comes next.
    throw: Option<Throw>,
    /// Where the mirror goes back to after a throw.
    return_to: Option<Vec2>,
}

impl RelayAgent {
    pub fn new(limits: &RelayLimits, geometry: &BenchGeometry) -> Self {
        let mut agent = Self {
            limits: limits.clone(),
            distances: geometry.station_distances_mm,
            image_side_px: geometry.image_px.map(|[w, h]| f64::from(w.min(h))),
            placement_px: geometry
                .placement_repeatability_mm
                .zip(geometry.pixel_pitch_mm())
                .map(|(spread, pitch)| spread / pitch[0].min(pitch[1])),
            px_per_step_mm: geometry
                .tilt_rad_per_step
                .zip(geometry.pixel_pitch_mm())
                .map(|(tilt, pitch)| {
                    // The smaller beam turn: 2 θ cos 45° (vertical tilt, 45° mirror).
                    2.0 * tilt * std::f64::consts::FRAC_1_SQRT_2 / pitch[0].max(pitch[1])
                }),
            station: 7,
            backdrops: Backdrops::new(8),
            ..Self::default()
        };
        agent.near = agent.new_near_servo();
        agent.search = agent.new_search();
        agent
    }

    /// The spot's nominal travel per step at `station`, px, when the geometry gives it.
    fn nominal_response(&self, station: usize) -> Option<f64> {
        self.px_per_step_mm
            .zip(self.distances)
            .map(|(r, d)| r * d[station])
    }

    /// The current mirror's search: a grid at the nominal response, else a growing cautious one.
    fn new_search(&self) -> Tracker {
        let bound = self.bound();
        let nominal = self
            .nominal_response(2 * self.mirror)
            .zip(self.image_side_px);
        let probe = nominal.map_or(CAUTIOUS_SHARE * 2.0 * bound, |(response, side)| {
            (RELAY_SEARCH_GRID_SHARE * side / response).clamp(1.0, self.widest_search())
        });
        Tracker::new([probe, probe], [[-bound, bound], [-bound, bound]])
    }

    fn widest_search(&self) -> f64 {
        MAX_SEARCH_SHARE * self.bound()
    }

    /// The bound on each axis's cumulative tilt, steps.
    fn bound(&self) -> f64 {
        f64::from(self.limits.max_cumulative)
    }

    /// The cumulative command of mirror `m` (vertical, horizontal), steps.
    fn command_of(&self, m: usize) -> Vec2 {
        [2 * m, 2 * m + 1].map(|a| f64::from(self.cumulative[a]))
    }

    /// The next action for a new frame; `rejected` means nothing happened.
    pub fn decide(&mut self, frame: &Frame, rejected: bool, remaining: usize) -> RelayAction {
        if !rejected {
            self.apply_last();
        }
        if let Some(action) = self.throw_under_way(frame, rejected) {
            return action;
        }
        let view = View::of(self.backdrops.picture(self.station, frame));
        let spot = self.find_spot(&view);
        self.seen_at = spot.map(|s| s.centre);
        let working = 2 * self.mirror + usize::from(self.phase == Phase::Far);
        let (size, centre) = (view.size(), view.centre());
        if remaining > MIN_REMAINING_TO_THROW
            && self.station == working
            && let Some(s) = spot.filter(|s| s.edge_level < WHOLE_ENOUGH_EDGE)
            && self.backdrops.wanted(self.station, &view.beams, &s)
            && let Some(throw) = self.throw_step(&s)
        {
            let tilt = self.command_of(self.mirror);
            self.throw = Some(self.backdrops.throw(self.station, frame, s, tilt, throw));
            self.previous = Some((view, self.station, self.cumulative));
            return self.act(tilt_by(self.mirror, throw.0));
        }
        self.previous = Some((view, self.station, self.cumulative));
        // Budget all but spent: end imaged at C8, done only if centred there (`far_phase`).
        if remaining <= 1 || (remaining <= 2 && self.station != 7) {
            return self.act(measure(7));
        }
        if self.station != working {
            return self.act(measure(working));
        }
        match self.phase {
            Phase::Near => self.near_phase(spot, centre, size),
            Phase::Far => self.far_phase(spot, centre, size),
        }
    }

    /// The spot in `view`: what moved after a tilt here (what stayed is stray), else the strongest.
    fn find_spot(&mut self, view: &View) -> Option<Beam> {
        let radius = self.radius.unwrap_or(default_radius(view.shorter_side()));
        let candidates: Vec<Beam> = view
            .beams
            .iter()
            .filter(|b| !self.stray_near(b.centre, STRAY_RADII * radius.max(b.size())))
            .copied()
            .collect();
        let steady = RELAY_STEADY_RADII * radius;
        // A faint change (a short move's edge, shifting speckle) is not the spot: the strongest is.
        let strongest_light = strongest(&candidates).map_or(0.0, |b| b.signal);
        if let Some((before, station, tilts)) = &self.previous
            && *station == self.station
            && *tilts != self.cumulative
            && let Some(seen) = motion(before, view, steady, None, None)
                .to
                .filter(|seen| seen.whole && seen.beam.signal >= MOVED_SHARE * strongest_light)
        {
            for (i, _) in stationary_pairs(&before.beams, &view.beams, steady) {
                let p = before.beams[i].centre;
                if !self.stray_near(p, STRAY_RADII * radius) {
                    self.stray.push((self.station, p));
                }
            }
            return Some(seen.beam);
        }
        strongest(&candidates).copied()
    }

    fn stray_near(&self, p: Vec2, within: f64) -> bool {
        self.stray
            .iter()
            .any(|(s, q)| *s == self.station && distance(*q, p) < within)
    }

    /// The next action of a throw under way, if any: learn the backdrop, then tilt back.
    fn throw_under_way(&mut self, frame: &Frame, rejected: bool) -> Option<RelayAction> {
        if let Some(mut throw) = self.throw.take().filter(|_| !rejected) {
            let outcome = self.backdrops.learn(&throw, frame);
            if outcome == Thrown::Learned {
                self.forget_sightings();
            }
            let further = [0, 1].map(|a| self.command_of(self.mirror)[a] + throw.step[a]);
            if outcome == Thrown::Short
                && throw.made < MAX_THROWS
                && further.iter().all(|c| c.abs() <= self.bound())
            {
                throw.made += 1;
                let step = throw.step;
                self.throw = Some(throw);
                return Some(self.act(tilt_by(self.mirror, step)));
            }
            self.return_to = Some(throw.tilt);
        }
        if let Some(tilt) = self.return_to.take().filter(|_| !rejected) {
            let view = View::of(self.backdrops.picture(self.station, frame));
            self.previous = Some((view, self.station, self.cumulative));
            let (action, arrives) = self.tilt_towards(tilt);
            self.return_to = (!arrives).then_some(tilt);
            return Some(self.act(action));
        }
        None
    }

    /// A one-axis tilt, steps, throwing `spot` [`THROW_RADII`] radii inwards, and its reach, px.
    fn throw_step(&self, spot: &Beam) -> Option<(Vec2, f64)> {
        let gain = self
            .servo()
            .gain()
            .or_else(|| self.assumed_gain(self.station));
        let nominal = self.nominal_response(self.station);
        let size = spot.size().max(self.radius.unwrap_or(0.0));
        if size < 1.0 {
            return None;
        }
        let wanted = THROW_RADII * size;
        let command = self.command_of(self.mirror);
        let mut best: Option<(f64, Vec2, f64)> = None;
        for axis in 0..2 {
            let response = gain
                .map(|g| g[0][axis].hypot(g[1][axis]))
                .or(nominal)
                .filter(|r| *r > 0.0)?;
            let steps = (wanted / response)
                .min(f64::from(self.limits.max_step))
                .round();
            let sign = if command[axis] > 0.0 { -1.0 } else { 1.0 };
            if (command[axis] + sign * steps).abs() <= self.bound()
                && best.is_none_or(|(s, _, _)| steps < s)
                && steps * response >= 2.0 * size
            {
                let step = [0, 1].map(|a| if a == axis { sign * steps } else { 0.0 });
                best = Some((steps, step, steps * response));
            }
        }
        best.map(|(_, step, reach)| (step, reach))
    }

    /// What the agent believes after its last decision, for the transcript.
    pub fn claims(&self) -> serde_json::Value {
        let stage = match self.phase {
            Phase::Near => "near station",
            Phase::Far => "far station",
        };
        let average = self.placements_average(self.command_of(3));
        let centre = self.previous.as_ref().map(|(view, _, _)| view.centre());
        let miss = average.zip(centre).map_or(0.0, |(a, c)| distance(a, c));
        serde_json::json!({
            "phase": format!("M{} at its {stage}", self.mirror + 1),
            "imaged_at": format!("C{}", self.station + 1),
            "spot_px": self.seen_at,
            "response_px_per_step": self.servo().gain(),
            "backdrops_at": self.backdrops.learned().map(|s| format!("C{}", s + 1)).collect::<Vec<_>>(),
            "c8_placements": {
                "made": self.placements.len(),
                "needed": self.placements_needed(miss),
                "average_px": average,
            },
        })
    }

    /// A servo at `station`, with response `gain` if known, else probes sized by the best guess.
    fn new_servo(&self, station: usize, gain: Option<[[f64; 2]; 2]>) -> Servo {
        let range = 2.0 * self.bound();
        let side = self.image_side_px.or_else(|| {
            self.previous
                .as_ref()
                .map(|(view, _, _)| view.shorter_side())
        });
        let known = self.assumed_gain(station).map(column_norm);
        let probe = match (self.nominal_response(station).or(known), side) {
            (Some(response), Some(side)) => useful_probe(side, response),
            _ => CAUTIOUS_SHARE * range,
        };
        Servo::new(probe, RELAY_PROBE_SHARES.map(|share| share * range), gain)
    }

    /// The near station's servo, starting from the latest near response measured as a guess.
    fn new_near_servo(&self) -> Servo {
        let near_station = 2 * self.mirror;
        self.new_servo(near_station, None)
            .assume(self.assumed_gain(near_station))
    }

    /// The latest near response measured, scaled to `station` by the stations' distances if known.
    fn assumed_gain(&self, station: usize) -> Option<[[f64; 2]; 2]> {
        let (gain, measured_at) = self.known_near?;
        let ratio = self.distances.map_or(1.0, |d| d[station] / d[measured_at]);
        Some(gain.map(|row| row.map(|v| v * ratio)))
    }

    /// The spot's centroid and whether it is whole enough to steer by (if cut, it points the way).
    fn estimate(&self, s: &Beam) -> Spot {
        let whole = s.edge_level < WHOLE_ENOUGH_EDGE;
        Spot {
            at: s.centre,
            whole,
            signal: s.signal,
            // A cut spot's centroid is pulled in by up to its size.
            scatter: if whole { s.uncertainty } else { s.size() }.max(MIN_NOISE_PX),
        }
    }

    /// At the near station: centre the spot (searching while never seen), then go to the far one.
    fn near_phase(&mut self, spot: Option<Beam>, centre: Vec2, size: Vec2) -> RelayAction {
        let u = self.command_of(self.mirror);
        let seen = spot.map(|s| self.estimate(&s));
        if let Some(s) = spot.filter(|s| !s.clipped) {
            self.radius = Some(s.size());
        }
        self.near.observe(u, seen, centre, size[0].min(size[1]));
        let near_station = 2 * self.mirror;
        if let Some(best) = self.near.best()
            && best.spot.whole
            && distance(best.spot.at, centre)
                < NEAR_CENTRED_SHARE * self.limits.centred_tolerance_px
            && best.tilt == u
        {
            let gain = self.near.gain();
            self.known_near = gain.map(|g| (g, near_station)).or(self.known_near);
            let scaled = self.assumed_gain(near_station + 1);
            self.far = self.new_servo(near_station + 1, gain.and(self.distances).and(scaled));
            self.far_steps = 0;
            self.far_dark = 0;
            self.far_start = u;
            self.phase = Phase::Far;
            return self.act(measure(near_station + 1));
        }
        if let Some(next) = self.near.next(centre) {
            return self.tilt_to(next);
        }
        self.search.add_missing(u);
        if self.search.missing.len() > 1 && self.nominal_response(2 * self.mirror).is_none() {
            let widest = self.widest_search();
            self.search.probe = self.search.probe.map(|p| (p * SEARCH_GROWTH).min(widest));
        }
        self.tilt_to(self.search.next_probe(self.near_start))
    }

    /// At the far station: centre the spot, searching around while dark; failing, back to the near.
    fn far_phase(&mut self, spot: Option<Beam>, centre: Vec2, size: Vec2) -> RelayAction {
        let u = self.command_of(self.mirror);
        let seen = spot.map(|s| self.estimate(&s));
        let last = self.mirror == 3;
        if last && self.placed && self.far.best().is_some() {
            // A new placement: what the servo saw in the last one is off by their difference.
            self.far = self.new_servo(7, self.far.gain());
        }
        if let Some(s) = seen.filter(|s| s.whole && last) {
            if !std::mem::take(&mut self.placed) {
                self.placements.pop();
            }
            self.placements.push((u, s.at));
        }
        // At C8, with several placements needed, aim so that their average is centred.
        let aimed = seen.filter(|s| s.whole && last && self.placements_needed(0.0) > 1);
        let target = aimed.map_or(centre, |s| {
            let average = self.placements_average(u).unwrap_or(s.at);
            [0, 1].map(|a| centre[a] + s.at[a] - average[a])
        });
        self.far.observe(u, seen, target, size[0].min(size[1]));
        let share = if last { DONE_SHARE } else { PASS_SHARE };
        // At C8 the spot must also be compact (a speckle cloud is no aligned beam).
        let compact = spot.is_some_and(|s| s.localised) || !last;
        if let Some(s) = seen
            && s.whole
            && compact
            && distance(s.at, target) < share * self.limits.centred_tolerance_px
        {
            if !last {
                self.next_mirror();
                return self.act(measure(2 * self.mirror));
            }
            let miss = distance(s.at, target);
            if self.placements.len() >= self.placements_needed(miss) {
                return self.act(RelayAction::Done);
            }
            // Too few placements yet: place the camera again (by way of C7).
            return self.act(measure(6));
        }
        if self.far.best().is_none() {
            self.far_dark += 1;
            if let Some(next) = self.far_search(size) {
                return self.tilt_to(next);
            }
        } else {
            self.far_steps += 1;
        }
        match self.far.next(target) {
            Some(next) if self.far_steps <= MAX_FAR_STEPS => self.tilt_to(next),
            _ => {
                self.phase = Phase::Near;
                self.near = self.new_near_servo();
                self.act(measure(2 * self.mirror))
            }
        }
    }

    /// The spot's place at tilt `u` averaged over C8's placements, each carried to `u`.
    fn placements_average(&self, u: Vec2) -> Option<Vec2> {
        let gain = self.far.gain().filter(|_| !self.placements.is_empty())?;
        let n = self.placements.len() as f64;
        let sum = self
            .placements
            .iter()
            .map(|&(tilt, at)| carried(gain, tilt, at, u))
            .fold([0.0; 2], |s, p| [s[0] + p[0], s[1] + p[1]]);
        Some(sum.map(|v| v / n))
    }

    /// C8 placements needed for the tolerance at [`DONE_CONFIDENCE`], their average `miss` px off.
    fn placements_needed(&self, miss: f64) -> usize {
        let spread = self
            .placement_px
            .unwrap_or(0.0)
            .max(self.placements_spread());
        let room = (self.limits.centred_tolerance_px - miss).max(f64::EPSILON);
        let needed = chi2_quantile(DONE_CONFIDENCE) * (spread / room).powi(2);
        (needed.ceil() as usize).max(1)
    }

    /// The mover's repeatability from consecutive C8 placements at one tilt, px (largest axis).
    fn placements_spread(&self) -> f64 {
        let differences: Vec<Vector2<f64>> = self
            .placements
            .windows(2)
            .filter(|pair| distance(pair[0].0, pair[1].0) < SAME_STEP)
            .map(|pair| Vector2::new(pair[1].1[0] - pair[0].1[0], pair[1].1[1] - pair[0].1[1]))
            .collect();
        if differences.is_empty() {
            return 0.0;
        }
        let scatter = differences
            .iter()
            .fold(Matrix2::zeros(), |sum, d| sum + d * d.transpose())
            / (2.0 * differences.len() as f64);
        scatter.symmetric_eigenvalues().max().max(0.0).sqrt()
    }

    /// The next tilt searching views around where the far spot was expected; `None` when done.
    fn far_search(&self, size: Vec2) -> Option<Vec2> {
        let gain = self.far.gain()?;
        let mut views = square_rings([0.0; 2], [1.0; 2], 1..=FAR_SEARCH_RINGS);
        views.sort_by(|a, b| a[0].hypot(a[1]).total_cmp(&b[0].hypot(b[1])));
        let view = *views.get(self.far_dark - 1)?;
        let offset = [0, 1].map(|a| -view[a] * FAR_SEARCH_OVERLAP * size[a]);
        let tilt = Affine::linear(gain).solve(offset)?;
        Some([self.far_start[0] + tilt[0], self.far_start[1] + tilt[1]])
    }

    /// Restarts the servo after a backdrop is learned, keeping its response as a guess.
    fn forget_sightings(&mut self) {
        let gain = self.servo().gain();
        match self.phase {
            Phase::Near => self.near = self.new_near_servo().assume(gain),
            Phase::Far => self.far = self.new_servo(self.station, None).assume(gain),
        }
    }

    fn servo(&self) -> &Servo {
        match self.phase {
            Phase::Near => &self.near,
            Phase::Far => &self.far,
        }
    }

    fn next_mirror(&mut self) {
        self.mirror += 1;
        self.phase = Phase::Near;
        self.search = self.new_search();
        self.near_start = self.command_of(self.mirror);
        self.near = self.new_near_servo();
    }

    /// Tilts the current mirror towards the command `target` (vertical, horizontal), within bounds.
    fn tilt_to(&mut self, target: Vec2) -> RelayAction {
        self.act(self.tilt_towards(target).0)
    }

    /// The tilt of [`Self::tilt_to`], at most the longest allowed per axis, and whether it arrives.
    fn tilt_towards(&self, target: Vec2) -> (RelayAction, bool) {
        let step = f64::from(self.limits.max_step);
        let bound = self.bound();
        let u = self.command_of(self.mirror);
        let wanted = [0, 1].map(|a| target[a].clamp(-bound, bound) - u[a]);
        let tilt = tilt_by(self.mirror, wanted.map(|w| w.clamp(-step, step).round()));
        (tilt, wanted.iter().all(|w| w.abs() <= step))
    }

    fn act(&mut self, action: RelayAction) -> RelayAction {
        self.last = Some(action.clone());
        action
    }

    /// Books the last action, now that it was executed.
    fn apply_last(&mut self) {
        match self.last.take() {
            Some(RelayAction::Tilt {
                mirror,
                vertical,
                horizontal,
            }) => {
                let m = usize::from(mirror);
                self.cumulative[2 * m] += vertical;
                self.cumulative[2 * m + 1] += horizontal;
            }
            Some(RelayAction::Measure { station }) => {
                if station.index() != self.station {
                    self.backdrops.arrived(station.index());
                }
                self.placed |= station.index() != self.station;
                self.station = station.index();
            }
            _ => {}
        }
    }
}

fn measure(station: usize) -> RelayAction {
    RelayAction::Measure {
        station: Station::from_index(station).unwrap_or(Station::C8),
    }
}

/// A tilt of `mirror` by `step` (vertical, horizontal), steps.
fn tilt_by(mirror: usize, step: Vec2) -> RelayAction {
    RelayAction::Tilt {
        mirror: mirror as u8,
        vertical: step[0] as i32,
        horizontal: step[1] as i32,
    }
}
