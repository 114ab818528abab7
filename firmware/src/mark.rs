//! The motion mark: which axes' saved positions cannot be trusted, kept apart from the
//! record so that it can be set before the first step of a move.
//!
//! The controller sets the mark for every axis of a move before that move's first step,
//! and shrinks it to the axes still flagged `POSITION_LOST` once the record holding the
//! end of the motion is written; a start-up that finds an axis marked flags it
//! `POSITION_LOST`. Encoding, [`MARK_LEN`] bytes: all 0xFF (erased flash) or all 0x00 (a
//! register after power-on) is no mark; `"OPTM"`, the axis bits (bit `n` for axis `n`),
//! their complement and two zero bytes mark those axes; anything else is garbled, and
//! marks every axis.

/// Bytes of an encoded mark.
pub const MARK_LEN: usize = 8;

const MAGIC: [u8; 4] = *b"OPTM";

/// The mark naming `axes` (bit `n` for axis `n`; 0 for no mark).
pub fn encode(axes: u8) -> [u8; MARK_LEN] {
    if axes == 0 {
        return [0xFF; MARK_LEN];
    }
    let [m0, m1, m2, m3] = MAGIC;
    [m0, m1, m2, m3, axes, !axes, 0, 0]
}

/// The axes a mark names; a garbled mark names every axis.
pub fn decode(mark: &[u8; MARK_LEN]) -> u8 {
    if mark.iter().all(|&b| b == 0xFF) || mark.iter().all(|&b| b == 0) {
        return 0;
    }
    match *mark {
        [m0, m1, m2, m3, axes, check, 0, 0] if [m0, m1, m2, m3] == MAGIC && check == !axes => axes,
        _ => u8::MAX,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_axis_set_round_trips() {
        for axes in 0..=u8::MAX {
            assert_eq!(decode(&encode(axes)), axes);
        }
    }

    #[test]
    fn blank_marks_name_nothing_and_garbled_ones_everything() {
        assert_eq!(decode(&[0xFF; MARK_LEN]), 0);
        assert_eq!(decode(&[0; MARK_LEN]), 0);
        let mut torn = encode(0b0101);
        torn[5] = 0xFF;
        assert_eq!(decode(&torn), u8::MAX);
        assert_eq!(decode(&[1, 2, 3, 4, 5, 6, 7, 8]), u8::MAX);
    }
}
