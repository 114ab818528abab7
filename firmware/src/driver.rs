//! The interface to the motor drivers, and the half-step coil sequence.

/// Physical sense of rotation of a motor (after the axis's `invert` is applied).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepDirection {
    Forward,
    Backward,
}

impl StepDirection {
    /// +1 for a forward step, -1 for a backward one: how a step moves the counter.
    pub fn sign(self) -> i32 {
        match self {
            Self::Forward => 1,
            Self::Backward => -1,
        }
    }
}

/// What the core asks of the hardware (or of a simulation).
///
/// `motor_steps` is the axis's physical step counter *after* the step: it moves by +1 for
/// every `Forward` step and -1 for every `Backward` one, so a ULN2003 driver energises
/// [`half_step_coils`]`(motor_steps)` and a STEP/DIR driver sets DIR and pulses STEP.
/// It is the counter the coils see, so it runs opposite to the logical motor counter
/// of an inverted axis.
pub trait StepDriver {
    /// Makes one step.
    fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32);
    /// Makes `count` steps in `direction`, the last leaving the counter at `motor_steps`:
    /// a run of one axis that was all due at once. One [`Self::step`] after another unless
    /// a driver can do better (a simulation).
    fn steps(&mut self, axis: u8, direction: StepDirection, count: u32, motor_steps: i32) {
        let delta = direction.sign();
        for left in (0..count).rev() {
            // Modular like the counter itself: `left as i32` wraps as the counter does.
            self.step(
                axis,
                direction,
                motor_steps.wrapping_sub(delta.wrapping_mul(left as i32)),
            );
        }
    }
    /// Energises (`on`: the coil pattern of `motor_steps`) or releases the axis's coils.
    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32);
}

/// 8-phase half-step sequence of a 28BYJ-48 through a ULN2003; bit 0 is IN1 (blue),
/// bit 3 is IN4 (orange).
const HALF_STEP: [u8; 8] = [
    0b0001, 0b0011, 0b0010, 0b0110, 0b0100, 0b1100, 0b1000, 0b1001,
];

/// The 4-bit coil pattern (IN1 = bit 0 .. IN4 = bit 3) for a motor step counter.
pub fn half_step_coils(motor_steps: i32) -> u8 {
    // rem_euclid(8) is always in 0..8.
    HALF_STEP[motor_steps.rem_euclid(8) as usize]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records every step it is given.
    #[derive(Default)]
    struct Log(Vec<(u8, StepDirection, i32)>);

    impl StepDriver for Log {
        fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32) {
            self.0.push((axis, direction, motor_steps));
        }
        fn set_power(&mut self, _: u8, _: bool, _: i32) {}
    }

    #[test]
    fn a_run_at_once_is_the_same_steps_one_by_one() {
        for (direction, delta) in [(StepDirection::Forward, 1), (StepDirection::Backward, -1)] {
            for last in [0, 5, i32::MAX, i32::MIN + 1] {
                let mut whole = Log::default();
                whole.steps(2, direction, 4, last);
                let one_by_one: Vec<_> = (0..4)
                    .rev()
                    .map(|left: i32| (2, direction, last.wrapping_sub(delta * left)))
                    .collect();
                assert_eq!(whole.0, one_by_one);
                let mut none = Log::default();
                none.steps(2, direction, 0, last);
                assert!(none.0.is_empty());
            }
        }
    }

    #[test]
    fn neighbouring_phases_differ_in_one_coil() {
        for steps in -20..20 {
            let change = half_step_coils(steps) ^ half_step_coils(steps + 1);
            assert_eq!(change.count_ones(), 1, "phase {steps}");
            assert!(half_step_coils(steps) != 0);
        }
        assert_eq!(half_step_coils(i32::MIN), half_step_coils(0));
        assert_eq!(half_step_coils(i32::MAX), half_step_coils(7));
    }
}
