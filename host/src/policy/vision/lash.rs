//! Lost motion of one relay mirror, learned as the agent goes: where the mount's load is
//! (in the play operator's convention, see `play`), the dead band of each axis, and the
//! command that puts the load at a target. The band grows when a reversal moves the spot
//! less than the measured response says the load should have moved, and shrinks when it
//! moves it more; between reversals nothing is lost, so only reversals teach it.

use super::model::Vec2;
use super::play::{self, settle};

/// A reversal teaches the band only when the load moved by more than this share of the
/// intended move away from it (less is read noise or a response not quite right).
const MISS_SHARE: f64 = 0.3;

/// Moves shorter than this many steps neither count as a direction nor teach the band.
const SAME_STEP: f64 = 0.5;

/// One mirror's lost motion.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Lash {
    /// The last command, steps.
    command: Vec2,
    /// The load's estimated position, steps.
    load: Vec2,
    /// The load before the last command.
    before: Vec2,
    /// The direction each axis last moved in (0 before its first move).
    heading: Vec2,
    /// Whether the last command reversed each axis.
    reversed: [bool; 2],
    /// The dead band of each axis, steps.
    band: Vec2,
}

impl Lash {
    /// Where the load is, as far as the agent knows.
    pub fn load(&self) -> Vec2 {
        self.load
    }

    /// The dead band learned so far, steps per axis.
    pub fn band(&self) -> Vec2 {
        self.band
    }

    /// Books that the mount was sent to `command`.
    pub fn moved(&mut self, command: Vec2) {
        self.before = self.load;
        for (axis, &to) in command.iter().enumerate() {
            let step = to - self.command[axis];
            if step.abs() < SAME_STEP {
                self.reversed[axis] = false;
                continue;
            }
            let direction = step.signum();
            self.reversed[axis] = self.heading[axis] == -direction;
            self.heading[axis] = direction;
        }
        self.command = command;
        self.load = settle(self.load, command, self.band);
    }

    /// The command that puts the load at `target` ([`play::command_for`]).
    pub fn command_for(&self, target: Vec2) -> Vec2 {
        play::command_for(target, self.load, self.band, self.command, SAME_STEP)
    }

    /// Learns from the last command, made from a load where the spot was seen, when the
    /// measured response says the load really moved by `moved` (steps per axis): an axis
    /// that reversed and moved less (or more) than intended has a wider (or narrower) band
    /// than assumed. Its load then trails the command by half the new band when the
    /// reversal took it along, and stayed where it was when it did not.
    pub fn learn(&mut self, from: Vec2, moved: Vec2) {
        if (0..2).any(|axis| (from[axis] - self.before[axis]).abs() > SAME_STEP) {
            // Commands were made since that sighting: the move is not the last command's.
            return;
        }
        for (axis, &moved) in moved.iter().enumerate() {
            let intended = self.load[axis] - self.before[axis];
            if !self.reversed[axis] || intended.abs() < SAME_STEP {
                continue;
            }
            let shortfall = (intended - moved) * intended.signum();
            if shortfall.abs() > MISS_SHARE * intended.abs() {
                self.band[axis] = (self.band[axis] + shortfall).max(0.0);
                let dragged = moved * intended.signum() > MISS_SHARE * intended.abs();
                self.load[axis] = if dragged {
                    self.command[axis] - self.heading[axis] * self.band[axis] / 2.0
                } else {
                    self.before[axis]
                };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::policy::vision::play::{Play, trajectory};

    /// A mount with a dead band of `band` on axis 0 and none on axis 1, driven by a `lash`
    /// that learns from each move (the response is known, so the load's move is seen).
    fn drive(band: f64, targets: &[f64]) -> (Lash, Vec<f64>) {
        let mut lash = Lash::default();
        let truth = Play {
            band: [band, 0.0],
            start: [0.0, 0.0],
        };
        let mut path = vec![[0.0, 0.0]];
        let mut errors = Vec::new();
        for &target in targets {
            let from = lash.load();
            let command = lash.command_for([target, 0.0]);
            path.push(command);
            lash.moved(command);
            let loads = trajectory(&path, truth);
            let now = loads[loads.len() - 1];
            let was = loads[loads.len() - 2];
            lash.learn(from, [now[0] - was[0], now[1] - was[1]]);
            errors.push(now[0] - target);
        }
        (lash, errors)
    }

    #[test]
    fn the_band_is_learned_from_reversals_and_then_compensated() {
        let targets = [2000.0, 1500.0, 2000.0, 1600.0, 1800.0, 1700.0, 1750.0];
        let (lash, errors) = drive(300.0, &targets);
        assert!((lash.band()[0] - 300.0).abs() < 1.0, "{:?}", lash.band());
        assert_eq!(lash.band()[1], 0.0);
        // Once learned, every move lands on its target, reversals included.
        for error in &errors[3..] {
            assert!(error.abs() < 1.0, "{errors:?}");
        }
    }

    #[test]
    fn a_mount_without_play_learns_no_band() {
        let (lash, errors) = drive(0.0, &[2000.0, 1000.0, 2000.0, 1200.0, 1800.0]);
        assert_eq!(lash.band(), [0.0, 0.0]);
        assert!(errors.iter().all(|e| e.abs() < 1e-9), "{errors:?}");
    }

    #[test]
    fn a_reversal_inside_the_band_widens_it_and_leaves_the_load() {
        let (lash, errors) = drive(300.0, &[2000.0, 1900.0]);
        assert!(lash.band()[0] >= 100.0, "{:?}", lash.band());
        // The load stayed where the first move left it, and the agent knows it.
        assert_eq!(errors[1], errors[0] + 100.0);
        assert_eq!(lash.load()[0], 2000.0);
    }
}
