//! A coordinated move in execution: phases of per-axis runs on absolute time.
//!
//! Each axis's path has one or two legs. Phases are aligned on the end: the last leg of
//! every axis runs in the last phase, so all axes of a move finish together, and the
//! OneSided overshoot legs run in the phase before. Every phase has one [`Shape`] shared by
//! its axes. Step times are absolute microseconds fixed at planning, so a late `poll`
//! makes the same steps on each axis, in the same order, as a punctual one. A run whose
//! every remaining step is due (a simulation that jumps to the end of a move, a very late
//! poll) is taken whole ([`Move::take_due_run`]), without timing its steps one by one.

use heapless::Vec;
use optalign_protocol::{AxisValue, MAX_AXES, MoveOutcome, RequestId};

use crate::gear::Travel;
use crate::path::{MAX_LEGS, Path, Segment};
use crate::ramp::{AxisDemand, Ramp, Shape};

/// What planning needs to know about one axis of a move.
pub struct AxisPlan {
    pub axis: u8,
    pub target: i32,
    pub path: Path,
    pub max_speed: u32,
    pub acceleration: u32,
}

/// A step that fell due.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Step {
    pub axis: u8,
    pub travel: Travel,
    pub at_us: u64,
}

/// Every step a run had left, taken at once because all of them were due.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DueRun {
    pub axis: u8,
    pub travel: Travel,
    pub steps: u32,
    /// When its last step fell due.
    pub last_at_us: u64,
}

/// One axis's steps within a phase.
#[derive(Clone, Debug)]
struct Run {
    axis: u8,
    travel: Travel,
    ramp: Ramp,
    origin_us: u64,
    done: u32,
    next_us: u64,
}

impl Run {
    fn new(axis: u8, travel: Travel, ramp: Ramp, origin_us: u64) -> Self {
        Self {
            axis,
            travel,
            ramp,
            origin_us,
            done: 0,
            next_us: origin_us.saturating_add(ramp.time_of(1)),
        }
    }

    fn remaining(&self) -> u32 {
        self.ramp.steps().saturating_sub(self.done)
    }

    fn is_done(&self) -> bool {
        self.remaining() == 0
    }

    fn end_us(&self) -> u64 {
        self.origin_us.saturating_add(self.ramp.duration_us())
    }

    /// When the run's last step falls due: no step of a ramp comes after its last one
    /// (every profile ends at its latest time), and [`Self::advance`] never moves a step
    /// before the one it follows.
    fn last_step_us(&self) -> u64 {
        let last = self.ramp.time_of(self.ramp.steps());
        self.next_us.max(self.origin_us.saturating_add(last))
    }

    /// Marks every remaining step made and returns them as one run.
    fn finish(&mut self) -> DueRun {
        let due = DueRun {
            axis: self.axis,
            travel: self.travel,
            steps: self.remaining(),
            last_at_us: self.last_step_us(),
        };
        self.next_us = due.last_at_us;
        self.done = self.ramp.steps();
        due
    }

    fn advance(&mut self) {
        self.done += 1;
        let next = self
            .origin_us
            .saturating_add(self.ramp.time_of(self.done + 1));
        self.next_us = self.next_us.max(next);
    }
}

type Phase = Vec<Run, MAX_AXES>;

/// A planned or running move.
#[derive(Clone, Debug)]
pub struct Move {
    request: RequestId,
    start_us: u64,
    targets: Vec<AxisValue, MAX_AXES>,
    phases: Vec<Phase, MAX_LEGS>,
    phase: usize,
    /// When the latest step was taken (the start until then).
    last_us: u64,
    started: bool,
    stopping: bool,
    cut: bool,
}

impl Move {
    /// Plans the move; `plans` holds at most one entry per axis.
    pub fn plan(request: RequestId, start_us: u64, plans: &[AxisPlan]) -> Self {
        let phase_count = plans.iter().map(|p| p.path.len()).max().unwrap_or(0);
        let mut phases = Vec::new();
        let mut origin = start_us;
        for phase in 0..phase_count {
            let legs = || {
                plans.iter().filter_map(move |plan| {
                    let first = phase_count - plan.path.len();
                    let leg = phase.checked_sub(first).and_then(|i| plan.path.get(i))?;
                    Some((plan, *leg))
                })
            };
            let demands = legs().map(|(plan, leg)| AxisDemand {
                steps: leg.motor_steps,
                max_speed: plan.max_speed,
                acceleration: plan.acceleration,
            });
            let Some(shape) = Shape::coordinated(demands) else {
                continue;
            };
            let mut runs = Phase::new();
            for (plan, leg) in legs().filter(|(_, leg)| leg.motor_steps > 0) {
                let ramp = shape.ramp(leg.motor_steps);
                // One run per axis: never more than MAX_AXES.
                let _ = runs.push(Run::new(plan.axis, leg.travel, ramp, origin));
            }
            origin = origin.saturating_add(shape.total_us());
            // At most MAX_LEGS phases.
            let _ = phases.push(runs);
        }
        let targets = plans
            .iter()
            .map(|p| AxisValue {
                axis: p.axis,
                steps: p.target,
            })
            .collect();
        Self {
            request,
            start_us,
            targets,
            phases,
            phase: 0,
            last_us: start_us,
            started: false,
            stopping: false,
            cut: false,
        }
    }

    pub fn request(&self) -> RequestId {
        self.request
    }

    pub fn start_us(&self) -> u64 {
        self.start_us
    }

    pub fn is_started(&self) -> bool {
        self.started
    }

    pub fn mark_started(&mut self) {
        self.started = true;
    }

    /// How the move ends if it runs out now.
    pub fn outcome(&self) -> MoveOutcome {
        if self.cut {
            MoveOutcome::Stopped
        } else {
            MoveOutcome::Completed
        }
    }

    /// The axes taking part.
    pub fn axes(&self) -> impl Iterator<Item = u8> + '_ {
        self.targets.iter().map(|t| t.axis)
    }

    /// The logical target of `axis`, if it takes part.
    pub fn target(&self, axis: u8) -> Option<i32> {
        self.targets
            .iter()
            .find(|t| t.axis == axis)
            .map(|t| t.steps)
    }

    fn remaining_runs(&self) -> impl Iterator<Item = &Run> {
        self.phases.iter().skip(self.phase).flatten()
    }

    /// Axes with steps still to make.
    pub fn stepping_axes(&self) -> impl Iterator<Item = u8> {
        let mut axes: Vec<u8, MAX_AXES> = Vec::new();
        for run in self.remaining_runs().filter(|r| !r.is_done()) {
            if !axes.contains(&run.axis) {
                let _ = axes.push(run.axis);
            }
        }
        axes.into_iter()
    }

    /// The motor travel `axis` still has to make, in order.
    pub fn remaining(&self, axis: u8) -> Path {
        let mut path = Path::new();
        for run in self
            .remaining_runs()
            .filter(|r| r.axis == axis && !r.is_done())
        {
            let _ = path.push(Segment {
                travel: run.travel,
                motor_steps: run.remaining(),
            });
        }
        path
    }

    /// The direction `axis` is travelling in now, if it is.
    pub fn travel(&self, axis: u8) -> Option<Travel> {
        self.phases
            .get(self.phase)?
            .iter()
            .find(|r| r.axis == axis && !r.is_done())
            .map(|r| r.travel)
    }

    pub fn is_finished(&self) -> bool {
        self.remaining_runs().all(Run::is_done)
    }

    /// When the next step falls due.
    pub fn next_step_us(&self) -> Option<u64> {
        self.phases.iter().skip(self.phase).find_map(|runs| {
            runs.iter()
                .filter(|r| !r.is_done())
                .map(|r| r.next_us)
                .min()
        })
    }

    /// When the last step will be (or was) made.
    pub fn end_us(&self) -> u64 {
        self.remaining_runs()
            .map(Run::end_us)
            .fold(self.last_us, u64::max)
    }

    /// Takes every step left of the current phase's first run whose last step is due at
    /// or before `now_us`: the steps [`Self::take_step`] would give for that axis one by
    /// one, in the same order, without timing each.
    pub fn take_due_run(&mut self, now_us: u64) -> Option<DueRun> {
        loop {
            let runs = self.phases.get_mut(self.phase)?;
            if runs.iter().all(Run::is_done) {
                self.phase += 1;
                continue;
            }
            let run = runs
                .iter_mut()
                .find(|r| !r.is_done() && r.last_step_us() <= now_us)?;
            let due = run.finish();
            self.last_us = self.last_us.max(due.last_at_us);
            return Some(due);
        }
    }

    /// Takes the earliest step due at or before `now_us` (ties in axis order).
    pub fn take_step(&mut self, now_us: u64) -> Option<Step> {
        loop {
            let runs = self.phases.get_mut(self.phase)?;
            match runs
                .iter_mut()
                .filter(|r| !r.is_done())
                .min_by_key(|r| r.next_us)
            {
                None => self.phase += 1,
                Some(run) if run.next_us <= now_us => {
                    let step = Step {
                        axis: run.axis,
                        travel: run.travel,
                        at_us: run.next_us,
                    };
                    run.advance();
                    self.last_us = step.at_us;
                    return Some(step);
                }
                Some(_) => return None,
            }
        }
    }

    /// Brings every axis to rest along its ramp from `at_us` (a coordinated stop); later
    /// phases are dropped. Steps that were due by `at_us` but not yet taken are kept.
    /// Stopping a stopping move changes nothing.
    pub fn stop(&mut self, at_us: u64) {
        if self.stopping {
            return;
        }
        self.stopping = true;
        while self
            .phases
            .get(self.phase)
            .is_some_and(|runs| runs.iter().all(Run::is_done))
        {
            self.phase += 1;
        }
        let later = self.phase + 1;
        if self
            .phases
            .iter()
            .skip(later)
            .flatten()
            .any(|r| !r.is_done())
        {
            self.cut = true;
        }
        self.phases.truncate(later);
        let Some(runs) = self.phases.get_mut(self.phase) else {
            return;
        };
        for run in runs.iter_mut().filter(|r| !r.is_done()) {
            let ramp = run.ramp.stop(run.done, at_us.saturating_sub(run.origin_us));
            if ramp.steps() < run.remaining() {
                self.cut = true;
            }
            *run = Run::new(run.axis, run.travel, ramp, at_us.max(run.origin_us));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(axis: u8, legs: &[(Travel, u32)]) -> AxisPlan {
        AxisPlan {
            axis,
            target: 0,
            path: legs
                .iter()
                .map(|&(travel, motor_steps)| Segment {
                    travel,
                    motor_steps,
                })
                .collect(),
            max_speed: 800,
            acceleration: 2000,
        }
    }

    fn drain(mv: &mut Move) -> std::vec::Vec<Step> {
        core::iter::from_fn(|| mv.take_step(u64::MAX)).collect()
    }

    #[test]
    fn phases_align_on_the_end() {
        let mut mv = Move::plan(
            RequestId(1),
            1000,
            &[
                plan(0, &[(Travel::Negative, 90), (Travel::Positive, 90)]),
                plan(1, &[(Travel::Positive, 300)]),
            ],
        );
        let end = mv.end_us();
        let steps = drain(&mut mv);
        let first_of_1 = steps.iter().position(|s| s.axis == 1).unwrap();
        // Axis 1 waits for axis 0's overshoot leg.
        assert_eq!(
            steps[..first_of_1].iter().filter(|s| s.axis == 0).count(),
            90
        );
        let last = |axis| steps.iter().rev().find(|s| s.axis == axis).unwrap().at_us;
        assert_eq!(last(0), end);
        assert_eq!(last(1), end);
        assert!(steps.windows(2).all(|w| w[0].at_us <= w[1].at_us));
        assert!(mv.is_finished());
    }

    #[test]
    fn stop_drops_later_phases_and_marks_the_cut() {
        let mut mv = Move::plan(
            RequestId(1),
            0,
            &[plan(0, &[(Travel::Negative, 500), (Travel::Positive, 500)])],
        );
        let at = mv.next_step_us().unwrap() + 200_000;
        while mv.take_step(at).is_some() {}
        mv.stop(at);
        assert_eq!(mv.outcome(), MoveOutcome::Stopped);
        assert!(mv.remaining(0).iter().all(|s| s.travel == Travel::Negative));
        let rest = drain(&mut mv);
        assert!(!rest.is_empty());
        assert!(mv.is_finished());
        assert_eq!(mv.end_us(), rest.last().unwrap().at_us);
    }

    #[test]
    fn stop_after_the_end_completes() {
        let mut mv = Move::plan(RequestId(1), 0, &[plan(0, &[(Travel::Positive, 50)])]);
        mv.stop(u64::MAX / 2);
        assert_eq!(drain(&mut mv).len(), 50);
        assert_eq!(mv.outcome(), MoveOutcome::Completed);
    }
}
