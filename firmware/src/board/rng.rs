//! Challenge nonces from the RP2040's ring oscillator (its RANDOMBIT register).

use embassy_rp::clocks::RoscRng;

use crate::session::RngSource;

/// The ring oscillator as the core's [`RngSource`].
pub struct Rosc;

impl RngSource for Rosc {
    fn fill(&mut self, buf: &mut [u8]) {
        RoscRng.fill_bytes(buf);
    }
}
