//! Moving lost axes while their positions are unknown: relative moves in the firmware's
//! recovery mode, each ending travelling in the axis's approach direction so that every
//! measuring position is approached from the same side and backlash does not bias it, the
//! travel counted so the axes can be brought back, and the pattern a search for a beam
//! out of view follows.

use anyhow::Context;
use optalign_protocol::{Approach, BacklashMode};

use crate::lab::rig::LabRig;

/// The overshoot before a final approach when the controller does not compensate: the
/// axis's configured backlash and margin, and at least this many steps.
pub const MIN_EXCURSION_STEPS: i32 = 100;

/// How one axis ends its moves on the approach side.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Side {
    /// +1 or -1, in task steps.
    pub direction: i32,
    /// Steps gone past a target against the approach before coming back to it.
    pub excursion: i32,
    /// The controller's one-sided compensation (with a backlash set) already ends every
    /// move this way.
    pub by_controller: bool,
}

/// The relative moves (one or two, each a delta per axis) that move the axes by `deltas`
/// and leave every one of them having arrived in its approach direction. `engaged` says
/// which axes already rest against their approach side (a zero delta then moves nothing).
pub fn legs(deltas: &[i32], sides: &[Side], engaged: &[bool]) -> Vec<Vec<i32>> {
    let mut first = vec![0; deltas.len()];
    let mut second = vec![0; deltas.len()];
    for (k, (&delta, side)) in deltas.iter().zip(sides).enumerate() {
        if engaged[k] && delta == 0 {
            continue;
        }
        if side.by_controller || (engaged[k] && delta.signum() == side.direction) {
            first[k] = delta;
        } else {
            first[k] = delta - side.direction * side.excursion;
            second[k] = side.direction * side.excursion;
        }
    }
    // A zero delta still matters to an unengaged axis the controller compensates: it takes
    // up the slack in place.
    let slack_in_place = sides
        .iter()
        .zip(engaged)
        .any(|(side, &engaged)| side.by_controller && !engaged);
    let mut moves = Vec::new();
    if slack_in_place || first.iter().any(|&d| d != 0) {
        moves.push(first);
    }
    if second.iter().any(|&d| d != 0) {
        moves.push(second);
    }
    moves
}

/// Lost axes on the move: where they went since the walk began, and which rest against
/// their approach side.
pub struct Walker {
    axes: Vec<usize>,
    sides: Vec<Side>,
    engaged: Vec<bool>,
    travelled: Vec<i64>,
}

impl Walker {
    /// A walk of task axes `axes`, reading each one's compensation from its controller.
    pub async fn new(rig: &LabRig, axes: &[usize]) -> anyhow::Result<Self> {
        let mut sides = Vec::new();
        for &axis in axes {
            let (client, controller_axis) = rig.controller_axis(axis);
            let config = client
                .get_config(controller_axis)
                .await
                .with_context(|| format!("reading the configuration of task axis {axis}"))?;
            let approach = match config.approach {
                Approach::Positive => 1,
                Approach::Negative => -1,
            };
            let excursion = i32::from(config.backlash).max(MIN_EXCURSION_STEPS)
                + i32::from(config.overshoot_margin);
            sides.push(Side {
                direction: rig.sign(axis) * approach,
                excursion,
                // Only a measured backlash makes the controller's overshoot enough.
                by_controller: config.backlash_mode == BacklashMode::OneSided
                    && config.backlash > 0,
            });
        }
        Ok(Self {
            axes: axes.to_vec(),
            engaged: vec![false; axes.len()],
            travelled: vec![0; axes.len()],
            sides,
        })
    }

    /// The approach direction of each axis (+1 or -1, task steps).
    pub fn directions(&self) -> Vec<i32> {
        self.sides.iter().map(|s| s.direction).collect()
    }

    /// Moves the axes by `deltas` (task steps, in the walker's axis order), arriving at the
    /// new position from the approach side.
    pub async fn go(&mut self, rig: &mut LabRig, deltas: &[i32]) -> anyhow::Result<()> {
        for leg in legs(deltas, &self.sides, &self.engaged) {
            let values: Vec<(usize, i32)> = self.axes.iter().copied().zip(leg).collect();
            rig.recovery_move(&values).await?;
        }
        for (k, &delta) in deltas.iter().enumerate() {
            self.travelled[k] += i64::from(delta);
            self.engaged[k] = true;
        }
        Ok(())
    }

    /// Brings the axes back to where the walk began (arriving from the approach side).
    pub async fn home(&mut self, rig: &mut LabRig) -> anyhow::Result<()> {
        let back: Vec<i32> = self
            .travelled
            .iter()
            .map(|&t| i32::try_from(-t).unwrap_or(0))
            .collect();
        self.go(rig, &back).await
    }
}

/// The grid points (in units of one search step per lost axis) a search visits, nearest
/// rings first, out to `rings`: ±1, ±2 … for one axis, the squares around the start for
/// two.
pub fn search_pattern(axes: usize, rings: i32) -> Vec<Vec<i32>> {
    let mut points = Vec::new();
    for ring in 1..=rings {
        match axes {
            1 => {
                points.push(vec![ring]);
                points.push(vec![-ring]);
            }
            _ => {
                // The ring's perimeter, walked round from its top-right corner.
                let mut cells = Vec::new();
                for i in -ring..ring {
                    cells.push(vec![ring, -i]);
                }
                for i in -ring..ring {
                    cells.push(vec![-i, -ring]);
                }
                for i in -ring..ring {
                    cells.push(vec![-ring, i]);
                }
                for i in -ring..ring {
                    cells.push(vec![i, ring]);
                }
                points.extend(cells);
            }
        }
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;

    const HOST: Side = Side {
        direction: 1,
        excursion: 100,
        by_controller: false,
    };

    #[test]
    fn every_move_ends_in_the_approach_direction() {
        // Unengaged: even a move the right way goes past first, so the slack is taken up.
        assert_eq!(legs(&[300], &[HOST], &[false]), vec![vec![200], vec![100]]);
        assert_eq!(legs(&[300], &[HOST], &[true]), vec![vec![300]]);
        assert_eq!(legs(&[-300], &[HOST], &[true]), vec![vec![-400], vec![100]]);
        // Measuring in place from an unknown slack: out and back.
        assert_eq!(legs(&[0], &[HOST], &[false]), vec![vec![-100], vec![100]]);
        assert!(legs(&[0], &[HOST], &[true]).is_empty());
        // Two axes: one leg for the axis already going the right way.
        let negative = Side {
            direction: -1,
            ..HOST
        };
        assert_eq!(
            legs(&[50, 50], &[HOST, negative], &[true, true]),
            vec![vec![50, 150], vec![0, -100]]
        );
        // The controller compensates: one leg, zeros included while the slack is unknown.
        let controller = Side {
            by_controller: true,
            ..HOST
        };
        assert_eq!(
            legs(&[-300, 0], &[controller, controller], &[false, false]),
            vec![vec![-300, 0]]
        );
        assert!(legs(&[0], &[controller], &[true]).is_empty());
    }

    #[test]
    fn the_search_visits_each_ring_once_nearest_first() {
        assert_eq!(
            search_pattern(1, 2),
            vec![vec![1], vec![-1], vec![2], vec![-2]]
        );
        let square = search_pattern(2, 2);
        assert_eq!(square.len(), 8 + 16);
        let mut unique = square.clone();
        unique.sort();
        unique.dedup();
        assert_eq!(unique.len(), square.len());
        assert!(square[..8].iter().all(|p| p[0].abs().max(p[1].abs()) == 1));
        assert!(!square.contains(&vec![0, 0]));
    }
}
