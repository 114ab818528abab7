//! Lost motion in a mount, as the play operator: where the load of a two-axis mount really
//! is after a history of commands when a dead band (backlash the controller does not
//! compensate) sits between motor and load, and the search for the band (and where in it
//! the mount started) that best explains what the images showed. A reversal shorter than
//! the band moves the motor only; a longer one drags the load along, trailing the motor by
//! half the band.

use super::model::Vec2;
use super::tuning::{PLAY_GRID_POINTS, PLAY_PASSES, PLAY_REFINED_MINIMA, PLAY_ROUNDS};

/// The play of a two-axis mount: the dead band of each axis, steps, and where in it the
/// load sat when the mount started, in half bands from the first command (-1: the gears
/// pressed as after a forward move, the load half a band behind; +1: as after a backward
/// move; 0: the middle).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Play {
    pub band: Vec2,
    pub start: Vec2,
}

/// Where the load sits once the motor goes to `command` from a load at `load`, with a band
/// of `band` steps per axis: an axis commanded within half the band of its load leaves it
/// where it is; beyond, the load trails the command by half the band.
pub fn settle(load: Vec2, command: Vec2, band: Vec2) -> Vec2 {
    [0, 1].map(|axis| {
        let half = band[axis] / 2.0;
        if command[axis] > load[axis] + half {
            command[axis] - half
        } else if command[axis] < load[axis] - half {
            command[axis] + half
        } else {
            load[axis]
        }
    })
}

/// The command that puts a load now at `load` at `target`, with a band of `band` steps per
/// axis: an axis whose load must move (by more than `same` steps) goes past the target by
/// half the band, on the side it approaches from; one already there stays at `current`.
pub fn command_for(target: Vec2, load: Vec2, band: Vec2, current: Vec2, same: f64) -> Vec2 {
    [0, 1].map(|axis| {
        let half = band[axis] / 2.0;
        if target[axis] > load[axis] + same {
            target[axis] + half
        } else if target[axis] < load[axis] - same {
            target[axis] - half
        } else {
            current[axis]
        }
    })
}

/// The load along a command `path` (the first command is where the mount started) for
/// the mount's `play`.
pub fn trajectory(path: &[Vec2], play: Play) -> Vec<Vec2> {
    let Some(&first) = path.first() else {
        return Vec::new();
    };
    let mut load = [0, 1].map(|a| first[a] + play.start[a] * play.band[a] / 2.0);
    path.iter()
        .map(|&command| {
            load = settle(load, command, play.band);
            load
        })
        .collect()
}

/// The widest band worth trying on each axis: the longest single move along it (a wider
/// band than any move ever made cannot be told from one that wide).
pub fn widest_band(path: &[Vec2]) -> Vec2 {
    let mut widest = [0.0; 2];
    for pair in path.windows(2) {
        for (axis, wide) in widest.iter_mut().enumerate() {
            *wide = f64::max(*wide, (pair[1][axis] - pair[0][axis]).abs());
        }
    }
    widest
}

/// One parameter of a play searched for.
#[derive(Clone, Copy)]
enum Parameter {
    Band,
    Start,
}

impl Parameter {
    fn of(self, play: &mut Play) -> &mut Vec2 {
        match self {
            Parameter::Band => &mut play.band,
            Parameter::Start => &mut play.start,
        }
    }

    /// The values it may take on an axis whose widest band is `widest`.
    fn range(self, widest: f64) -> (f64, f64) {
        match self {
            Parameter::Band => (0.0, widest),
            Parameter::Start => (-1.0, 1.0),
        }
    }
}

/// The play on `axes` (bands from 0 to `widest`, starts from -1 to 1) that minimises
/// `misfit`, starting from `from`, one parameter at a time: a grid over its range, the
/// grid's lowest local minima refined, and of the values whose misfit is within
/// `tolerance` of the lowest, the one nearest 0 (the narrowest band, the middle start).
/// The misfit of a play operator is piecewise smooth with kinks where a reversal starts
/// or stops moving the load, so a descent may stall; and with few sightings a band wider
/// than most moves can explain them as well as the true one, by freezing the load, so of
/// two explanations alike the simpler is kept.
pub fn best_play(
    from: Play,
    axes: &[usize],
    widest: Vec2,
    tolerance: f64,
    misfit: impl Fn(Play) -> f64,
) -> Play {
    let mut best = from;
    for _ in 0..PLAY_ROUNDS {
        for &axis in axes {
            for parameter in [Parameter::Band, Parameter::Start] {
                best = best_value(best, axis, parameter, widest[axis], tolerance, &misfit);
            }
        }
    }
    best
}

/// `base` with `parameter` of `axis` (an axis whose widest band is `widest`) set to the
/// value [`best_play`] takes for it, the others held.
fn best_value(
    base: Play,
    axis: usize,
    parameter: Parameter,
    widest: f64,
    tolerance: f64,
    misfit: &impl Fn(Play) -> f64,
) -> Play {
    let at = |value: f64| {
        let mut play = base;
        parameter.of(&mut play)[axis] = value;
        play
    };
    let (floor, ceiling) = parameter.range(widest);
    let cell = (ceiling - floor) / (PLAY_GRID_POINTS - 1) as f64;
    let grid: Vec<(f64, f64)> = (0..PLAY_GRID_POINTS)
        .map(|i| floor + cell * i as f64)
        .map(|value| (value, misfit(at(value))))
        .collect();
    // A plateau's minimum is its first point.
    let mut minima: Vec<(f64, f64)> = (0..grid.len())
        .filter(|&i| {
            let left = i == 0 || grid[i].1 < grid[i - 1].1;
            let right = grid.get(i + 1).is_none_or(|next| grid[i].1 <= next.1);
            left && right
        })
        .map(|i| grid[i])
        .collect();
    minima.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut current = base;
    let mut candidates = vec![(parameter.of(&mut current)[axis], misfit(base))];
    for &(value, value_misfit) in minima.iter().take(PLAY_REFINED_MINIMA) {
        let (mut centre, mut lowest, mut width) = (value, value_misfit, cell);
        for _ in 1..PLAY_PASSES {
            let (low, high) = ((centre - width).max(floor), (centre + width).min(ceiling));
            width = (high - low) / (PLAY_GRID_POINTS - 1) as f64;
            for i in 0..PLAY_GRID_POINTS {
                let value = low + width * i as f64;
                let value_misfit = misfit(at(value));
                if value_misfit < lowest {
                    (centre, lowest) = (value, value_misfit);
                }
            }
        }
        candidates.push((centre, lowest));
    }
    // One candidate per basin, its lowest; then the simplest of those alike.
    candidates.sort_by(|a, b| a.1.total_cmp(&b.1));
    let mut basins: Vec<(f64, f64)> = Vec::new();
    for candidate in candidates {
        if basins.iter().all(|b| (b.0 - candidate.0).abs() > cell) {
            basins.push(candidate);
        }
    }
    let lowest = basins.first().map_or(f64::INFINITY, |b| b.1);
    basins
        .iter()
        .filter(|b| b.1 <= lowest + tolerance)
        .min_by(|a, b| a.0.abs().total_cmp(&b.0.abs()))
        .map_or(base, |&(value, _)| at(value))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_reversal_shorter_than_the_band_leaves_the_load_where_it_was() {
        let band = [300.0, 0.0];
        let path = [
            [0.0, 0.0],
            [1000.0, 0.0],
            [900.0, 0.0],
            [600.0, 0.0],
            [700.0, 0.0],
        ];
        let play = Play {
            band,
            start: [0.0; 2],
        };
        let loads: Vec<f64> = trajectory(&path, play).iter().map(|l| l[0]).collect();
        // Forward: 150 behind; back 100 (inside the band): still; back to 600: 150 ahead;
        // forward 100: still.
        assert_eq!(loads, vec![0.0, 850.0, 850.0, 750.0, 750.0]);
    }

    #[test]
    fn the_play_that_explains_the_positions_is_found() {
        let truth = Play {
            band: [240.0, 90.0],
            start: [-1.0, 0.5],
        };
        let path = [
            [0.0, 0.0],
            [100.0, 30.0],
            [1500.0, 200.0],
            [1400.0, 1500.0],
            [-600.0, 1450.0],
            [-500.0, -900.0],
            [800.0, -800.0],
            [700.0, 600.0],
        ];
        let seen = trajectory(&path, truth);
        let misfit = |play: Play| {
            trajectory(&path, play)
                .iter()
                .zip(&seen)
                .map(|(a, b)| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2))
                .sum::<f64>()
        };
        let found = best_play(Play::default(), &[0, 1], widest_band(&path), 1e-6, misfit);
        for axis in 0..2 {
            assert!(
                (found.band[axis] - truth.band[axis]).abs() < 1.0,
                "{found:?}"
            );
        }
        // Where the mount started shows in the loads until the first move leaves the band.
        for (found, truth) in trajectory(&path, found).iter().zip(&seen) {
            assert!(
                (found[0] - truth[0]).abs() < 1.0 && (found[1] - truth[1]).abs() < 1.0,
                "{found:?} {truth:?}"
            );
        }
    }

    #[test]
    fn of_two_explanations_alike_the_narrower_band_is_kept() {
        // With few sightings a band wider than most moves can fit them as well as the true
        // one, by freezing the load: the grid's coarse cells may miss the true basin's floor,
        // but it is refined and preferred.
        let misfit = |play: Play| {
            let band = play.band[0];
            if band > 5000.0 {
                0.0
            } else {
                1e-3 * (band - 230.0).powi(2)
            }
        };
        let found = best_play(Play::default(), &[0], [5600.0, 0.0], 0.5, misfit);
        assert!((found.band[0] - 230.0).abs() < 25.0, "{found:?}");
    }
}
