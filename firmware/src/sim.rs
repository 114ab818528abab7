//! A mechanical model of a motorised mount, a driver that moves it, and a deterministic
//! random source: for tests and for the host's simulated peer (feature `sim`).
//!
//! [`MountModel`] is the truth the firmware's backlash model tries to track: a motor
//! geared to a load through a dead band of `backlash` steps, with optional lost steps
//! (random, or in a binding region of load positions). Everything is deterministic given
//! the seed.

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
        }
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
            let next = self.shaft.saturating_add(if forward { 1 } else { -1 });
            if let Some(stall) = &self.stall
                && (stall.min..=stall.max).contains(&next)
                && self.rng.chance(stall.threshold)
            {
                self.lost += 1;
                return false;
            }
            self.shaft = next;
        } else if forward {
            self.play += 1;
        } else {
            self.play -= 1;
        }
        self.motor = self.motor.wrapping_add(if forward { 1 } else { -1 });
        true
    }

    /// The true load position, in steps.
    pub fn shaft_position(&self) -> i32 {
        self.shaft
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
