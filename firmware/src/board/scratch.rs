//! The motion mark in the watchdog's scratch registers 0 and 1: they keep it through a
//! watchdog reset or a software reboot, and read as no mark after a power cut.
//!
//! Flash would keep it through a power cut too, but programming flash stalls the step
//! back-ends; see `docs/protocol.md` ("Honest positions") for what that leaves uncovered.

use embassy_rp::pac::WATCHDOG;

use crate::mark::MARK_LEN;

/// The mark as the registers hold it.
pub fn read() -> [u8; MARK_LEN] {
    let mut mark = [0; MARK_LEN];
    let (low, high) = mark.split_at_mut(4);
    low.copy_from_slice(&WATCHDOG.scratch0().read().to_le_bytes());
    high.copy_from_slice(&WATCHDOG.scratch1().read().to_le_bytes());
    mark
}

/// Stores `mark`.
pub fn write(mark: &[u8; MARK_LEN]) {
    let [a, b, c, d, e, f, g, h] = *mark;
    WATCHDOG
        .scratch0()
        .write_value(u32::from_le_bytes([a, b, c, d]));
    WATCHDOG
        .scratch1()
        .write_value(u32::from_le_bytes([e, f, g, h]));
}
