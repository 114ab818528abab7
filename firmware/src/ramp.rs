//! Trapezoidal step timing in integer microseconds.
//!
//! All axes of one coordinated phase follow one normalised profile s(t) from 0 to 1:
//! constant acceleration A up to speed V (reached at `accel_us`), cruise, and a mirrored
//! deceleration ending at `total_us` (a triangle when the phase is too short to reach V).
//! An axis with n steps makes step k when n·s(t) reaches k, so its speed is n·V and its
//! acceleration n·A. V and A are the largest values that keep every axis within its own
//! `max_speed` and `acceleration`, so no axis exceeds its limits and all finish together.
//!
//! Planning (once per phase) uses `u128`; the per-step work is one `u64` integer square
//! root or a multiply-add, never a float or a division by a variable wide type. With
//! m = 2/(n·A) in µs² per step, Ta = `accel_us` and T = `total_us`, step k of n is at
//! - accelerating: √(m·k)
//! - cruising: Ta/2 + k·(T − Ta)/n
//! - decelerating: T − √(m·(n − k))
//!
//! The bounds of [`crate::config`] keep m·k below Ta² ≤ 4·10^18 in the square-root regions
//! and every product inside a `u64`.

const MICROS: u128 = 1_000_000;
const MICROS_SQUARED: u128 = MICROS * MICROS;

/// What one axis asks of a phase: its step count and its own limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisDemand {
    pub steps: u32,
    /// Steps per second.
    pub max_speed: u32,
    /// Steps per second squared.
    pub acceleration: u32,
}

/// The normalised profile shared by the axes of one phase.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    accel_us: u64,
    total_us: u64,
    /// The normalised acceleration A is `accel / accel_steps` per second squared.
    accel: u64,
    accel_steps: u64,
}

fn saturate(value: u128) -> u64 {
    u64::try_from(value).unwrap_or(u64::MAX)
}

impl Shape {
    /// The fastest common profile for these axes, or `None` when none has a step to make.
    pub fn coordinated(demands: impl IntoIterator<Item = AxisDemand>) -> Option<Self> {
        // Normalised limits are v/n and a/n; keep the smallest of each as a fraction.
        let mut speed: Option<(u128, u128)> = None;
        let mut accel: Option<(u128, u128)> = None;
        for demand in demands {
            if demand.steps == 0 {
                continue;
            }
            let n = u128::from(demand.steps);
            let v = u128::from(demand.max_speed.max(1));
            let a = u128::from(demand.acceleration.max(1));
            if speed.is_none_or(|(sv, sn)| v * sn < sv * n) {
                speed = Some((v, n));
            }
            if accel.is_none_or(|(sa, sn)| a * sn < sa * n) {
                accel = Some((a, n));
            }
        }
        let (v, nv) = speed?;
        let (a, na) = accel?;
        // V²/A ≥ 1: the whole distance is spent accelerating and braking.
        let (accel_us, total_us) = if v * v * na >= nv * nv * a {
            let accel_us = saturate(na * MICROS_SQUARED / a).isqrt();
            (accel_us, accel_us.saturating_mul(2))
        } else {
            let accel_us = saturate(v * na * MICROS / (nv * a));
            (accel_us, accel_us.saturating_add(saturate(nv * MICROS / v)))
        };
        Some(Self {
            accel_us,
            total_us,
            accel: saturate(a),
            accel_steps: saturate(na),
        })
    }

    /// Duration of the phase.
    pub fn total_us(&self) -> u64 {
        self.total_us
    }

    /// The schedule of an axis making `steps` steps in this phase.
    pub fn ramp(&self, steps: u32) -> Ramp {
        let n = u128::from(steps.max(1));
        let m =
            2 * MICROS_SQUARED * u128::from(self.accel_steps) / (n * u128::from(self.accel.max(1)));
        let span = u128::from(self.total_us.saturating_sub(self.accel_us));
        Ramp {
            steps,
            profile: Profile::Trapezoid {
                m: saturate(m),
                accel_us: self.accel_us,
                total_us: self.total_us,
                per_step_us: saturate(span / n),
                per_step_rem: saturate(span % n),
            },
        }
    }
}

/// When each step of one axis's run happens, relative to the run's origin.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Ramp {
    steps: u32,
    profile: Profile,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Profile {
    /// Accelerate, cruise, decelerate (see the module documentation).
    Trapezoid {
        m: u64,
        accel_us: u64,
        total_us: u64,
        per_step_us: u64,
        per_step_rem: u64,
    },
    /// Brake from the origin to rest over `brake_us`: `lag` steps that were already due
    /// run at once, then step j of the rest comes when the distance left to the resting
    /// point, `reach/m − j` steps, shrinks to zero along the ramp: at
    /// `brake_us − √(reach − m·j)`. `reach` is m times the (fractional) distance to rest.
    Brake {
        lag: u32,
        m: u64,
        brake_us: u64,
        reach: u128,
    },
}

impl Ramp {
    pub fn steps(&self) -> u32 {
        self.steps
    }

    /// Time of step `k` (1-based; clamped to the run) after the origin.
    pub fn time_of(&self, k: u32) -> u64 {
        let k = k.min(self.steps);
        let n = self.steps;
        match self.profile {
            Profile::Trapezoid {
                m,
                accel_us,
                total_us,
                per_step_us,
                per_step_rem,
            } => {
                let knee = accel_us.saturating_mul(accel_us);
                if 2 * u64::from(k) <= u64::from(n) {
                    if let Some(x) = m.checked_mul(u64::from(k))
                        && x < knee
                    {
                        return x.isqrt();
                    }
                } else if let Some(x) = m.checked_mul(u64::from(n - k))
                    && x < knee
                {
                    return total_us.saturating_sub(x.isqrt());
                }
                let k = u64::from(k);
                (accel_us / 2)
                    .saturating_add(k.saturating_mul(per_step_us))
                    .saturating_add(k.saturating_mul(per_step_rem) / u64::from(n.max(1)))
            }
            Profile::Brake {
                lag,
                m,
                brake_us,
                reach,
            } => {
                if k <= lag {
                    0
                } else {
                    let left = reach.saturating_sub(u128::from(m) * u128::from(k - lag));
                    brake_us.saturating_sub(saturate(left).isqrt())
                }
            }
        }
    }

    /// Time of the last step (0 for an empty run).
    pub fn duration_us(&self) -> u64 {
        if self.steps == 0 {
            0
        } else {
            self.time_of(self.steps)
        }
    }

    /// The run brought to rest as fast as it may brake, from `at_us` after the origin, when
    /// `done` steps have been made. The result's origin is `at_us` and it counts steps from
    /// `done`: first the steps due by `at_us` and not yet made, then the braking distance
    /// (never beyond the original end), continuing from the exact fractional position
    /// reached at `at_us`. Braking uses this axis's share of the phase's acceleration, so
    /// the axes of a phase still come to rest together.
    pub fn stop(&self, done: u32, at_us: u64) -> Ramp {
        let done = done.min(self.steps);
        let due = self.due_by(done, at_us);
        let (m, travelled, brake_us) = match self.profile {
            Profile::Trapezoid {
                m,
                accel_us,
                total_us,
                ..
            } => {
                let at = at_us.min(total_us);
                let whole = u128::from(m) * u128::from(self.steps);
                let travelled = if at <= accel_us {
                    u128::from(at) * u128::from(at)
                } else if at >= total_us.saturating_sub(accel_us) {
                    whole.saturating_sub(u128::from(total_us - at).pow(2))
                } else {
                    let span = u128::from(total_us - accel_us).max(1);
                    whole * u128::from(at - accel_us / 2) / span
                };
                (m, travelled, at.min(accel_us).min(total_us - at))
            }
            Profile::Brake {
                lag,
                m,
                brake_us,
                reach,
            } => {
                let left = brake_us.saturating_sub(at_us);
                let travelled = u128::from(m) * u128::from(lag) + reach;
                (m, travelled.saturating_sub(u128::from(left).pow(2)), left)
            }
        };
        let m_wide = u128::from(m.max(1));
        // m × the part of a step made beyond the last due step, kept within [0, 1).
        let fraction = travelled
            .saturating_sub(m_wide * u128::from(due))
            .min(m_wide - 1);
        let reach = fraction + u128::from(brake_us).pow(2);
        let remaining = self.steps - due;
        let braking = u32::try_from(reach / m_wide)
            .unwrap_or(u32::MAX)
            .min(remaining);
        Ramp {
            steps: due - done + braking,
            profile: Profile::Brake {
                lag: due - done,
                m,
                brake_us,
                reach,
            },
        }
    }

    /// The last step at or before `at_us`, searching from `done` (step times never decrease).
    fn due_by(&self, done: u32, at_us: u64) -> u32 {
        let (mut low, mut high) = (done, self.steps);
        while low < high {
            let mid = low + (high - low).div_ceil(2);
            if self.time_of(mid) <= at_us {
                low = mid;
            } else {
                high = mid - 1;
            }
        }
        low
    }
}

#[cfg(test)]
mod tests {
    use proptest::prelude::*;

    use super::*;

    fn demand(steps: u32, max_speed: u32, acceleration: u32) -> AxisDemand {
        AxisDemand {
            steps,
            max_speed,
            acceleration,
        }
    }

    fn times(ramp: &Ramp) -> std::vec::Vec<u64> {
        (1..=ramp.steps()).map(|k| ramp.time_of(k)).collect()
    }

    /// Checks speed and acceleration against the limits from the step times alone.
    /// `rest_after` is how far (in steps, below 1) the profile may go on braking after its
    /// last step: a stopped run rests at a fractional position and halts at the last whole
    /// step.
    fn assert_within(times: &[u64], max_speed: u32, acceleration: u32, rest_after: f64) {
        let v = f64::from(max_speed);
        let a = f64::from(acceleration);
        let n = times.len();
        let end = *times.last().unwrap() as f64 * 1e-6;
        for (i, pair) in times.windows(2).enumerate() {
            assert!(pair[1] >= pair[0], "step {} goes back in time", i + 2);
            // A few microseconds of integer rounding per step time (the knee between the
            // accelerating and cruising formulas).
            let dt = (pair[1] - pair[0] + 3) as f64 * 1e-6;
            assert!(
                1.0 / dt <= v * 1.000_1,
                "step {}: speed {} > {v}",
                i + 2,
                1.0 / dt
            );
        }
        for (i, &t) in times.iter().enumerate() {
            let t = t as f64 * 1e-6 + 2e-6;
            let k = (i + 1) as f64;
            // From rest, k steps need √(2k/a); and from step k, n − k steps to rest.
            assert!(t >= (2.0 * k / a).sqrt() * 0.999, "step {k} too early");
            let left = (n - i - 1) as f64;
            let slack = 4e-6 + (2.0 * rest_after / a).sqrt();
            assert!(
                end - t + slack >= (2.0 * left / a).sqrt() * 0.999,
                "step {k} cannot brake"
            );
        }
    }

    #[test]
    fn one_step_and_two_steps() {
        let shape = Shape::coordinated([demand(1, 800, 2000)]).unwrap();
        // Triangle over one step: 2·√(1/2000) s.
        assert_eq!(shape.total_us(), 2 * 22_360);
        assert_eq!(times(&shape.ramp(1)), [44_720]);
        let shape = Shape::coordinated([demand(2, 800, 2000)]).unwrap();
        assert_eq!(times(&shape.ramp(2)), [31_622, 63_244]);
    }

    #[test]
    fn long_move_cruises_at_max_speed() {
        let shape = Shape::coordinated([demand(4096, 800, 2000)]).unwrap();
        // 0.4 s ramps and 4096/800 s at speed: 5.52 s.
        assert_eq!(shape.total_us(), 5_520_000);
        let ramp = shape.ramp(4096);
        let t = times(&ramp);
        assert_eq!(t[2047] - t[2046], 1250);
        assert_eq!(*t.last().unwrap(), 5_520_000);
        assert_within(&t, 800, 2000, 0.0);
    }

    #[test]
    fn no_steps_no_shape() {
        assert_eq!(Shape::coordinated([demand(0, 800, 2000)]), None);
        assert_eq!(Shape::coordinated([]), None);
    }

    #[test]
    fn stop_brakes_within_the_acceleration() {
        let shape = Shape::coordinated([demand(10_000, 1000, 500)]).unwrap();
        let ramp = shape.ramp(10_000);
        let full = times(&ramp);
        // Stop at cruise: braking takes as many steps as the acceleration did (1000).
        let at = 5_000_000;
        let done = full.iter().filter(|&&t| t <= at).count() as u32;
        let stop = ramp.stop(done, at);
        assert_eq!(stop.steps(), 1000);
        let mut joined: std::vec::Vec<u64> = full[..done as usize].to_vec();
        joined.extend(times(&stop).iter().map(|t| t + at));
        assert_within(&joined, 1000, 500, 1.0);
        // A stop before the first step stops at once; one after the end changes nothing.
        assert_eq!(ramp.stop(0, 0).steps(), 0);
        assert_eq!(ramp.stop(0, u64::MAX).steps(), 10_000);
        assert_eq!(ramp.stop(0, u64::MAX).duration_us(), 0);
    }

    #[test]
    fn stop_runs_late_steps_at_once() {
        let ramp = Shape::coordinated([demand(100, 800, 2000)])
            .unwrap()
            .ramp(100);
        let at = ramp.time_of(40);
        let stop = ramp.stop(10, at);
        assert_eq!(stop.time_of(30), 0);
        assert!(stop.time_of(31) > 0);
        assert!(stop.steps() > 30 && stop.steps() <= 90);
    }

    proptest! {
        #[test]
        fn single_axis_respects_limits(n in 1u32..3000, v in 1u32..=20_000, a in 10u32..=500_000) {
            let shape = Shape::coordinated([demand(n, v, a)]).unwrap();
            let t = times(&shape.ramp(n));
            prop_assert_eq!(*t.last().unwrap(), shape.total_us());
            assert_within(&t, v, a, 0.0);
        }

        #[test]
        fn coordinated_axes_share_the_end_and_keep_their_limits(
            axes in prop::collection::vec((0u32..2000, 1u32..=5000, 10u32..=50_000), 1..5)
        ) {
            let demands: std::vec::Vec<AxisDemand> =
                axes.iter().map(|&(n, v, a)| demand(n, v, a)).collect();
            let Some(shape) = Shape::coordinated(demands.iter().copied()) else {
                prop_assert!(axes.iter().all(|&(n, ..)| n == 0));
                return Ok(());
            };
            for d in demands.iter().filter(|d| d.steps > 0) {
                let t = times(&shape.ramp(d.steps));
                prop_assert_eq!(*t.last().unwrap(), shape.total_us());
                assert_within(&t, d.max_speed, d.acceleration, 0.0);
            }
        }

        #[test]
        fn stopping_anywhere_keeps_the_limits(n in 2u32..3000, v in 1u32..=5000, a in 10u32..=50_000, at in 0.0f64..1.2) {
            let ramp = Shape::coordinated([demand(n, v, a)]).unwrap().ramp(n);
            let full = times(&ramp);
            let at = (ramp.duration_us() as f64 * at) as u64;
            let done = full.iter().filter(|&&t| t <= at).count() as u32;
            let stop = ramp.stop(done, at);
            prop_assert!(done + stop.steps() <= n);
            let mut joined: std::vec::Vec<u64> = full[..done as usize].to_vec();
            joined.extend(times(&stop).iter().map(|t| t + at));
            if !joined.is_empty() {
                assert_within(&joined, v, a, 1.0);
            }
        }
    }
}
