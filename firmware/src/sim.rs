//! A mechanical model of a motorised mount, a driver that moves it, and a deterministic
//! random source: for tests and for the host's simulated peer (feature `sim`).
//!
//! [`MountModel`] is the truth the firmware's backlash model tries to track: a motor
//! geared to a load through a dead band of `backlash` steps, with optional lost steps
//! (random, or in a binding region of load positions), and an optional imperfect screw
//! between the load and the mirror (a periodic pitch error, and elastic hysteresis that
//! lags the mirror behind reversals beyond the dead band). Everything is deterministic
//! given the seed.

use heapless::Vec;
use optalign_protocol::MAX_AXES;

use crate::driver::{StepDirection, StepDriver};
use crate::session::RngSource;

/// A small deterministic generator (SplitMix64).
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SimRng(u64);

impl SimRng {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// True with `probability` (a threshold out of 2^32, see [`threshold`]).
    fn chance(&mut self, threshold: u64) -> bool {
        (self.next_u64() >> 32) < threshold
    }
}

impl RngSource for SimRng {
    fn fill(&mut self, buf: &mut [u8]) {
        for chunk in buf.chunks_mut(8) {
            let bytes = self.next_u64().to_le_bytes();
            chunk.copy_from_slice(&bytes[..chunk.len()]);
        }
    }
}

/// A probability in 0..=1 as a threshold out of 2^32.
fn threshold(probability: f32) -> u64 {
    let p = if probability.is_nan() {
        0.0
    } else {
        probability.clamp(0.0, 1.0)
    };
    (p * 4_294_967_296.0) as u64
}

/// A load positions region where the screw binds.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
struct Stall {
    min: i32,
    max: i32,
    threshold: u64,
}

/// A motor driving a load through a gear train with backlash.
///
/// Positions are in motor steps. `play` is where the motor sits in the dead band: 0 means
/// pressed against the load in the negative direction, `backlash` in the positive one. A
/// step inside the band moves only the motor; a step pressing a contact moves the load.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct MountModel {
    backlash: u32,
    play: u32,
    shaft: i32,
    motor: i32,
    lost_step: u64,
    stall: Option<Stall>,
    rng: SimRng,
    lost: u64,
    screw: Screw,
}

/// Imperfections of the screw between the load and the mirror.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
struct Screw {
    /// Amplitude of the periodic pitch error, steps.
    pitch_error: u32,
    /// Its period, steps.
    pitch_period: u32,
    /// Half the width of the elastic hysteresis loop, steps.
    hysteresis: u32,
    /// How far the mirror lags the screw now, thousandths of a step (+ after forward travel).
    wind_milli: i32,
}

impl Screw {
    /// After one load step in `direction`, the lag relaxes towards the full half-width on
    /// that side: right after a reversal the mirror does not follow at all, then catches up
    /// over a few times the half-width.
    fn load_step(&mut self, forward: bool) {
        if self.hysteresis == 0 {
            return;
        }
        let full = 1000 * i64::from(self.hysteresis) * if forward { 1 } else { -1 };
        let gap = full - i64::from(self.wind_milli);
        self.wind_milli += (gap / (2 * i64::from(self.hysteresis))) as i32;
    }

    /// The mirror position for screw position `shaft`, steps.
    fn mirror(&self, shaft: i32) -> i32 {
        let periodic = if self.pitch_error == 0 || self.pitch_period == 0 {
            0.0
        } else {
            let phase = core::f64::consts::TAU
                * f64::from(shaft.rem_euclid(self.pitch_period as i32))
                / f64::from(self.pitch_period);
            f64::from(self.pitch_error) * libm::sin(phase)
        };
        let lag = f64::from(self.wind_milli) / 1000.0;
        shaft.saturating_add(libm::round(periodic - lag) as i32)
    }
}

impl MountModel {
    /// A mount with a dead band of `backlash` steps, load and motor at 0, the gear train
    /// pressed in the positive direction (where a OneSided-Positive move leaves it).
    pub fn new(backlash: u32) -> Self {
        Self {
            backlash,
            play: backlash,
            shaft: 0,
            motor: 0,
            lost_step: 0,
            stall: None,
            rng: SimRng::new(0x6F70_7461_6C69_676E),
            lost: 0,
            screw: Screw::default(),
        }
    }

    /// An imperfect screw: a periodic pitch error of `pitch_error` steps amplitude every
    /// `pitch_period` steps, and elastic hysteresis of `hysteresis` steps either side.
    pub fn with_screw(mut self, pitch_error: u32, pitch_period: u32, hysteresis: u32) -> Self {
        self.screw = Screw {
            pitch_error,
            pitch_period,
            hysteresis,
            wind_milli: 1000 * hysteresis.min(i32::MAX as u32 / 1000) as i32,
        };
        self
    }

    /// Starts with the motor `play` steps above the negative contact (clamped to the band).
    pub fn with_play(mut self, play: u32) -> Self {
        self.play = play.min(self.backlash);
        self
    }

    /// Seeds the generator behind lost steps.
    pub fn with_seed(mut self, seed: u64) -> Self {
        self.rng = SimRng::new(seed);
        self
    }

    /// Every step is lost (the rotor slips, nothing moves) with `probability`.
    pub fn with_lost_steps(mut self, probability: f32) -> Self {
        self.lost_step = threshold(probability);
        self
    }

    /// A step that would move the load to a position in `min..=max` is lost with
    /// `probability` (1 makes the region a hard stop, less a binding screw).
    pub fn with_stall_region(mut self, min: i32, max: i32, probability: f32) -> Self {
        self.stall = Some(Stall {
            min,
            max,
            threshold: threshold(probability),
        });
        self
    }

    /// Applies one motor step; returns whether the rotor turned.
    pub fn apply_step(&mut self, direction: StepDirection) -> bool {
        if self.rng.chance(self.lost_step) {
            self.lost += 1;
            return false;
        }
        let forward = direction == StepDirection::Forward;
        let presses = if forward {
            self.play >= self.backlash
        } else {
            self.play == 0
        };
        if presses {
            let next = self.shaft.saturating_add(direction.sign());
            if let Some(stall) = &self.stall
                && (stall.min..=stall.max).contains(&next)
                && self.rng.chance(stall.threshold)
            {
                self.lost += 1;
                return false;
            }
            self.shaft = next;
            self.screw.load_step(forward);
        } else if forward {
            self.play += 1;
        } else {
            self.play -= 1;
        }
        self.motor = self.motor.wrapping_add(direction.sign());
        true
    }

    /// The true load position, in steps.
    pub fn shaft_position(&self) -> i32 {
        self.shaft
    }

    /// Where the mirror really is, in steps: the load position through the screw's pitch
    /// error and hysteresis (the load position itself on a perfect screw).
    pub fn mirror_position(&self) -> i32 {
        self.screw.mirror(self.shaft)
    }

    /// The true rotor position, in steps.
    pub fn motor_position(&self) -> i32 {
        self.motor
    }

    /// Steps above the negative contact of the dead band.
    pub fn play(&self) -> u32 {
        self.play
    }

    pub fn backlash(&self) -> u32 {
        self.backlash
    }

    /// Steps lost so far.
    pub fn lost_steps(&self) -> u64 {
        self.lost
    }
}

/// A [`StepDriver`] moving one [`MountModel`] per axis. A step sent to an axis whose coils
/// are off moves nothing and is counted in [`Self::unpowered_steps`].
#[derive(Clone, Debug)]
pub struct SimDriver {
    mounts: Vec<MountModel, MAX_AXES>,
    powered: [bool; MAX_AXES],
    coil_steps: [i32; MAX_AXES],
    unpowered_steps: u64,
}

impl SimDriver {
    /// One mount per axis, in axis order (extra mounts beyond `MAX_AXES` are ignored).
    pub fn new(mounts: impl IntoIterator<Item = MountModel>) -> Self {
        Self {
            mounts: mounts.into_iter().take(MAX_AXES).collect(),
            powered: [false; MAX_AXES],
            coil_steps: [0; MAX_AXES],
            unpowered_steps: 0,
        }
    }

    pub fn mount(&self, axis: u8) -> Option<&MountModel> {
        self.mounts.get(usize::from(axis))
    }

    pub fn mount_mut(&mut self, axis: u8) -> Option<&mut MountModel> {
        self.mounts.get_mut(usize::from(axis))
    }

    pub fn is_powered(&self, axis: u8) -> bool {
        self.powered
            .get(usize::from(axis))
            .copied()
            .unwrap_or(false)
    }

    /// The last step counter the driver was given for `axis`.
    pub fn coil_steps(&self, axis: u8) -> i32 {
        self.coil_steps.get(usize::from(axis)).copied().unwrap_or(0)
    }

    /// Steps commanded while the axis's coils were off.
    pub fn unpowered_steps(&self) -> u64 {
        self.unpowered_steps
    }
}

impl StepDriver for SimDriver {
    fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32) {
        let index = usize::from(axis);
        if let Some(counter) = self.coil_steps.get_mut(index) {
            *counter = motor_steps;
        }
        if !self.is_powered(axis) {
            self.unpowered_steps += 1;
            return;
        }
        if let Some(mount) = self.mounts.get_mut(index) {
            mount.apply_step(direction);
        }
    }

    fn steps(&mut self, axis: u8, direction: StepDirection, count: u32, motor_steps: i32) {
        let index = usize::from(axis);
        if let Some(counter) = self.coil_steps.get_mut(index) {
            *counter = motor_steps;
        }
        if !self.is_powered(axis) {
            self.unpowered_steps += u64::from(count);
            return;
        }
        if let Some(mount) = self.mounts.get_mut(index) {
            for _ in 0..count {
                mount.apply_step(direction);
            }
        }
    }

    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32) {
        let index = usize::from(axis);
        if let Some(powered) = self.powered.get_mut(index) {
            *powered = on;
        }
        if let Some(counter) = self.coil_steps.get_mut(index) {
            *counter = motor_steps;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    use StepDirection::{Backward, Forward};

    #[test]
    fn a_run_at_once_moves_the_mounts_as_its_steps_one_by_one() {
        let mounts = || {
            [
                MountModel::new(7)
                    .with_seed(3)
                    .with_lost_steps(0.05)
                    .with_stall_region(-40, -10, 0.3),
                MountModel::new(0).with_seed(9).with_lost_steps(0.01),
            ]
        };
        let (mut whole, mut stepped) = (SimDriver::new(mounts()), SimDriver::new(mounts()));
        for driver in [&mut whole, &mut stepped] {
            driver.set_power(0, true, 0);
        }
        // Axis 0 powered; axis 1 not, so its steps are only counted.
        let runs = [
            (0, Backward, 60),
            (1, Forward, 25),
            (0, Forward, 90),
            (0, Backward, 5),
        ];
        let mut counters = [0i32; 2];
        for (axis, direction, count) in runs {
            let delta = direction.sign();
            let first = counters[usize::from(axis)];
            let last = first + delta * count;
            whole.steps(axis, direction, count as u32, last);
            for step in 1..=count {
                stepped.step(axis, direction, first + delta * step);
            }
            counters[usize::from(axis)] = last;
        }
        for axis in 0..2 {
            assert_eq!(whole.mount(axis), stepped.mount(axis));
            assert_eq!(whole.coil_steps(axis), stepped.coil_steps(axis));
        }
        assert_eq!(whole.unpowered_steps(), 25);
        assert_eq!(whole.unpowered_steps(), stepped.unpowered_steps());
        assert!(whole.mount(0).is_some_and(|m| m.lost_steps() > 0));
    }

    #[test]
    fn dead_band_then_load() {
        let mut mount = MountModel::new(3);
        mount.apply_step(Forward);
        assert_eq!((mount.shaft_position(), mount.motor_position()), (1, 1));
        for _ in 0..3 {
            mount.apply_step(Backward);
        }
        assert_eq!((mount.shaft_position(), mount.play()), (1, 0));
        mount.apply_step(Backward);
        assert_eq!(mount.shaft_position(), 0);
        let mut mount = MountModel::new(3).with_play(1);
        mount.apply_step(Forward);
        assert_eq!((mount.shaft_position(), mount.play()), (0, 2));
    }

    #[test]
    fn a_perfect_screw_puts_the_mirror_on_the_load() {
        let mut mount = MountModel::new(0);
        for _ in 0..100 {
            mount.apply_step(Forward);
        }
        assert_eq!(mount.mirror_position(), 100);
    }

    #[test]
    fn pitch_error_is_periodic_in_the_load_position() {
        let mut mount = MountModel::new(0).with_screw(20, 400, 0);
        let mut seen = [0; 4];
        for step in 1..=400 {
            mount.apply_step(Forward);
            if step % 100 == 0 {
                seen[step / 100 - 1] = mount.mirror_position() - mount.shaft_position();
            }
        }
        // sin at a quarter, half, three quarters and a whole period.
        assert_eq!(seen, [20, 0, -20, 0]);
    }

    #[test]
    fn hysteresis_lags_the_mirror_after_a_reversal() {
        let mut mount = MountModel::new(0).with_screw(0, 0, 50);
        for _ in 0..1000 {
            mount.apply_step(Forward);
        }
        // Settled lag: 50 steps behind on the forward side.
        assert_eq!(mount.shaft_position() - mount.mirror_position(), 50);
        let before = mount.mirror_position();
        for _ in 0..20 {
            mount.apply_step(Backward);
        }
        // The mirror hardly follows the first steps back ...
        assert!(
            before - mount.mirror_position() < 8,
            "{}",
            before - mount.mirror_position()
        );
        for _ in 0..980 {
            mount.apply_step(Backward);
        }
        // ... and lags 50 steps on the other side once settled: a loop 100 steps wide.
        assert_eq!(mount.mirror_position() - mount.shaft_position(), 50);
    }

    #[test]
    fn hard_stall_region_blocks_the_load() {
        let mut mount = MountModel::new(0).with_stall_region(5, 10, 1.0);
        for _ in 0..20 {
            mount.apply_step(Forward);
        }
        assert_eq!(mount.shaft_position(), 4);
        assert_eq!(mount.lost_steps(), 16);
        assert!(mount.apply_step(Backward));
        assert_eq!(mount.shaft_position(), 3);
    }

    #[test]
    fn lost_steps_follow_the_probability_and_the_seed() {
        let run = |seed| {
            let mut mount = MountModel::new(0).with_lost_steps(0.25).with_seed(seed);
            for _ in 0..10_000 {
                mount.apply_step(Forward);
            }
            mount.lost_steps()
        };
        assert_eq!(run(1), run(1));
        assert!((2300..2700).contains(&run(1)), "{}", run(1));
        assert_eq!(MountModel::new(0).with_lost_steps(f32::NAN).lost_step, 0);
    }

    #[test]
    fn unpowered_steps_do_not_move() {
        let mut driver = SimDriver::new([MountModel::new(0)]);
        driver.step(0, Forward, 1);
        assert_eq!(driver.unpowered_steps(), 1);
        driver.set_power(0, true, 1);
        driver.step(0, Forward, 2);
        assert_eq!(driver.mount(0).unwrap().shaft_position(), 1);
        driver.step(7, Forward, 2);
        assert_eq!(driver.unpowered_steps(), 2);
    }
}
