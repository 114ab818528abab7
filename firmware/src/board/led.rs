//! The status LED (the Pico W's LED hangs off the CYW43439's GPIO 0).
//!
//! | pattern | meaning |
//! |---|---|
//! | two short flashes every 1.5 s | fault: an axis reports one (emergency stop latched, position lost), a record write failed, or a step was dropped |
//! | fast blink, 5 Hz | a move is running |
//! | steady on | on the Wi-Fi network, idle |
//! | slow blink, 1 Hz | no Wi-Fi: no credentials, joining, or waiting to retry |
//!
//! Listed from the highest priority down: a fault shows over motion, motion over the
//! network state.

use cyw43::Control;
use embassy_time::Timer;
use portable_atomic::Ordering;

use super::events::DROPPED;
use super::flash::FAILED_WRITES;
use super::motion::{ENGAGED, FAULT};

/// One LED phase: lit or not, for how long (ms).
type Phase = (bool, u64);

const FAULT_PATTERN: &[Phase] = &[(true, 100), (false, 150), (true, 100), (false, 1150)];
const MOVING: &[Phase] = &[(true, 100), (false, 100)];
const CONNECTED: &[Phase] = &[(true, 250)];
const NO_WIFI: &[Phase] = &[(true, 500), (false, 500)];

/// The pattern for the board's state.
fn pattern(connected: bool) -> &'static [Phase] {
    let fault = FAULT.load(Ordering::Relaxed)
        || FAILED_WRITES.load(Ordering::Relaxed) > 0
        || DROPPED.load(Ordering::Relaxed) > 0;
    if fault {
        FAULT_PATTERN
    } else if ENGAGED.load(Ordering::Relaxed) {
        MOVING
    } else if connected {
        CONNECTED
    } else {
        NO_WIFI
    }
}

/// Shows the board's state forever (run it in a `select` with whatever it waits for).
pub async fn show(control: &mut Control<'static>, connected: bool) -> ! {
    loop {
        for &(lit, ms) in pattern(connected) {
            control.gpio_set(0, lit).await;
            Timer::after_millis(ms).await;
        }
    }
}
