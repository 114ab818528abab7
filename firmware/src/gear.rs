//! The believed state of an axis's gear train inside its dead band (backlash).
//!
//! The motor sits somewhere in a dead band `backlash` steps wide: `band` counts the steps
//! it is above the negative contact, so `band == 0` means it is pressed against the load in
//! the negative direction and `band == backlash` in the positive one. A motor step inside
//! the band takes up slack and leaves the load where it is; only a step that pushes against
//! a contact moves the load. The logical position follows the load, so slack steps never
//! enter it, while the motor step counter counts every step.
//!
//! When the side is [`Slack::Unknown`] (a board without a stored record) the model assumes
//! the gear train rests against the contact *opposite* the first travel, so the first move
//! takes up the whole band: the load may then travel up to `backlash` steps further than
//! the logical position says (once; it defines the origin), but afterwards the gear train
//! is pressed against a known contact, whatever its real starting state was.

use optalign_protocol::{Approach, Slack};

/// A direction of travel in logical coordinates.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Travel {
    Positive,
    Negative,
}

impl Travel {
    /// The direction of a non-zero difference.
    pub fn of(delta: i64) -> Option<Self> {
        match delta.signum() {
            1 => Some(Self::Positive),
            -1 => Some(Self::Negative),
            _ => None,
        }
    }

    pub fn sign(self) -> i32 {
        match self {
            Self::Positive => 1,
            Self::Negative => -1,
        }
    }

    pub fn reverse(self) -> Self {
        match self {
            Self::Positive => Self::Negative,
            Self::Negative => Self::Positive,
        }
    }

    fn slack(self) -> Slack {
        match self {
            Self::Positive => Slack::TakenUpPositive,
            Self::Negative => Slack::TakenUpNegative,
        }
    }

    /// The band position of the contact this travel pushes against.
    fn contact(self, backlash: u16) -> u16 {
        match self {
            Self::Positive => backlash,
            Self::Negative => 0,
        }
    }
}

impl From<Approach> for Travel {
    fn from(approach: Approach) -> Self {
        match approach {
            Approach::Positive => Self::Positive,
            Approach::Negative => Self::Negative,
        }
    }
}

/// Where the motor is inside the dead band, and which way it last travelled.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Gear {
    slack: Slack,
    band: u16,
}

impl Gear {
    /// Nothing known (fresh board).
    pub const UNKNOWN: Self = Self {
        slack: Slack::Unknown,
        band: 0,
    };

    /// A stored state, kept consistent with `backlash`.
    pub fn restore(slack: Slack, band: u16, backlash: u16) -> Self {
        match slack {
            Slack::Unknown => Self::UNKNOWN,
            _ => Self {
                slack,
                band: band.min(backlash),
            },
        }
    }

    /// The direction of the last travel (what the status reports).
    pub fn slack(self) -> Slack {
        self.slack
    }

    /// Steps above the negative contact.
    pub fn band(self) -> u16 {
        self.band
    }

    /// Where the motor is assumed to start a travel in `travel`.
    fn start(self, travel: Travel, backlash: u16) -> u16 {
        match self.slack {
            Slack::Unknown => travel.reverse().contact(backlash),
            _ => self.band.min(backlash),
        }
    }

    /// Motor steps in `travel` before the load starts to move.
    pub fn take_up(self, travel: Travel, backlash: u16) -> u16 {
        let start = self.start(travel, backlash);
        match travel {
            Travel::Positive => backlash - start,
            Travel::Negative => start,
        }
    }

    /// Whether the motor is known to press the load in `travel`.
    pub fn is_engaged(self, travel: Travel, backlash: u16) -> bool {
        self.slack != Slack::Unknown && self.take_up(travel, backlash) == 0
    }

    /// One motor step in `travel`; returns whether it moved the load.
    pub fn step(&mut self, travel: Travel, backlash: u16) -> bool {
        let start = self.start(travel, backlash);
        let (band, moved) = match travel {
            Travel::Positive if start < backlash => (start + 1, false),
            Travel::Negative if start > 0 => (start - 1, false),
            _ => (start, true),
        };
        *self = Self {
            slack: travel.slack(),
            band,
        };
        moved
    }

    /// The state after `steps` motor steps in `travel`, and how many of them moved the load.
    pub fn advance(self, travel: Travel, steps: u32, backlash: u16) -> (Self, u32) {
        if steps == 0 {
            return (self, 0);
        }
        let take_up = self.take_up(travel, backlash);
        let load = steps.saturating_sub(u32::from(take_up));
        // Fewer steps than the take-up: the motor stops inside the band.
        let inside = u16::try_from(steps).unwrap_or(u16::MAX).min(take_up);
        let start = self.start(travel, backlash);
        let band = match travel {
            Travel::Positive => start + inside,
            Travel::Negative => start - inside,
        };
        let gear = Self {
            slack: travel.slack(),
            band,
        };
        (gear, load)
    }

    /// The same physical state described for a different configured backlash: the distance
    /// from the contact last pushed against is kept (clamped to the new band).
    pub fn rebase(self, old_backlash: u16, new_backlash: u16) -> Self {
        let band = match self.slack {
            Slack::Unknown => 0,
            Slack::TakenUpPositive => {
                new_backlash.saturating_sub(old_backlash.saturating_sub(self.band))
            }
            Slack::TakenUpNegative => self.band.min(new_backlash),
        };
        Self {
            slack: self.slack,
            band,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reversal_takes_up_the_band_before_the_load_moves() {
        let mut gear = Gear::restore(Slack::TakenUpPositive, 40, 40);
        assert!(gear.is_engaged(Travel::Positive, 40));
        assert_eq!(gear.take_up(Travel::Negative, 40), 40);
        let moved: u32 = (0..45)
            .map(|_| u32::from(gear.step(Travel::Negative, 40)))
            .sum();
        assert_eq!(moved, 5);
        assert_eq!(gear.slack(), Slack::TakenUpNegative);
        assert_eq!(gear.band(), 0);
    }

    #[test]
    fn unknown_assumes_the_opposite_contact() {
        assert_eq!(Gear::UNKNOWN.take_up(Travel::Positive, 30), 30);
        assert_eq!(Gear::UNKNOWN.take_up(Travel::Negative, 30), 30);
        assert!(!Gear::UNKNOWN.is_engaged(Travel::Positive, 0));
        let mut gear = Gear::UNKNOWN;
        assert!(!gear.step(Travel::Positive, 30));
        assert_eq!(gear.band(), 1);
    }

    #[test]
    fn advance_matches_stepping() {
        for start in [
            Gear::UNKNOWN,
            Gear::restore(Slack::TakenUpPositive, 7, 12),
            Gear::restore(Slack::TakenUpNegative, 3, 12),
        ] {
            for travel in [Travel::Positive, Travel::Negative] {
                for steps in 0..30 {
                    let mut gear = start;
                    let moved: u32 = (0..steps).map(|_| u32::from(gear.step(travel, 12))).sum();
                    assert_eq!(start.advance(travel, steps, 12), (gear, moved));
                }
            }
        }
    }

    #[test]
    fn rebase_keeps_the_distance_from_the_last_contact() {
        let gear = Gear::restore(Slack::TakenUpPositive, 38, 40);
        assert_eq!(gear.rebase(40, 20).band(), 18);
        assert_eq!(gear.rebase(40, 1).band(), 0);
        let gear = Gear::restore(Slack::TakenUpNegative, 5, 40);
        assert_eq!(gear.rebase(40, 3).band(), 3);
        assert_eq!(Gear::UNKNOWN.rebase(0, 10), Gear::UNKNOWN);
    }
}
