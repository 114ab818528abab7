//! Step timing by the hardware timer, for the emulator image: one task per axis waits for
//! each event's time and sets the axis's four GPIOs.
//!
//! rp2040js runs its PIO model from wall-clock callbacks rather than emulated cycles, so
//! the emulator image plays the same event queues with embassy-time alarms instead; an
//! edge lands one interrupt-and-task wake-up after its time (about 5-12 µs there). The
//! Pico W image uses PIO ([`super::pio_steps`]).

use embassy_rp::gpio::{Level, Output};
use embassy_time::{Instant, Timer};

use super::AXES;
use super::events::{Event, PULSE_US, Queue, SETUP_US, STEP};

/// Plays `queue` on `pins` (bit 0 first) forever.
#[embassy_executor::task(pool_size = AXES as usize)]
pub async fn run(queue: &'static Queue, mut pins: [Output<'static>; 4]) -> ! {
    let mut current = 0u8;
    loop {
        let event: Event = queue.receive().await;
        if event.pulse {
            let rest = event.pattern & !STEP;
            if rest != current {
                drive(&mut pins, event.at_us.saturating_sub(SETUP_US), rest).await;
            }
            drive(&mut pins, event.at_us, event.pattern).await;
            drive(&mut pins, event.at_us.saturating_add(PULSE_US), rest).await;
            current = rest;
        } else {
            drive(&mut pins, event.at_us, event.pattern).await;
            current = event.pattern;
        }
    }
}

async fn drive(pins: &mut [Output<'static>; 4], at_us: u64, pattern: u8) {
    Timer::at(Instant::from_micros(at_us)).await;
    for (bit, pin) in pins.iter_mut().enumerate() {
        pin.set_level(Level::from(pattern & (1 << bit) != 0));
    }
}
