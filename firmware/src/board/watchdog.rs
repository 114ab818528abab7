//! The hardware watchdog, fed only while the main loops make progress.
//!
//! The motion task (high-priority executor) checks in on every round; the feeding loop
//! itself runs in the thread-mode executor with the links. The watchdog is fed only when
//! both have run since the last feed, so a wedged executor, a stuck motion task or a
//! starved thread mode resets the board; after the reset the axes come back at their
//! persisted positions with their coils off.

use embassy_rp::watchdog::Watchdog;
use embassy_time::{Duration, Timer};
use portable_atomic::{AtomicU32, Ordering};

use super::log::warn;

/// Check-in bit of the motion task.
pub const MOTION: u32 = 1 << 0;
const REQUIRED: u32 = MOTION;

/// Time to come up (the Wi-Fi firmware upload takes about a second); the RP2040 allows
/// at most 8.3 s.
pub const BOOT_TIMEOUT: Duration = Duration::from_secs(8);
const TIMEOUT: Duration = Duration::from_secs(2);
const FEED_PERIOD: Duration = Duration::from_millis(500);

static CHECK_INS: AtomicU32 = AtomicU32::new(0);

/// Records that the loop behind `bit` made progress.
pub fn check_in(bit: u32) {
    CHECK_INS.fetch_or(bit, Ordering::Relaxed);
}

/// Feeds the watchdog while every loop checks in.
#[embassy_executor::task]
pub async fn run(mut watchdog: Watchdog) -> ! {
    loop {
        Timer::after(FEED_PERIOD).await;
        let seen = CHECK_INS.swap(0, Ordering::Relaxed);
        if seen & REQUIRED == REQUIRED {
            watchdog.feed(TIMEOUT);
        } else {
            warn!(
                "watchdog: no check-in from {:#x}; not feeding",
                REQUIRED & !seen
            );
        }
    }
}
