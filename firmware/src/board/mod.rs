//! The RP2040 layer: executes what the firmware core decides, on real pins and links.
//!
//! Two images share it. The Pico W image (feature `board`) serves the protocol over TCP on
//! Wi-Fi and over USB CDC-ACM, times steps with PIO state machines and keeps the record in
//! flash. The emulator image (feature `emu`) serves it over UART0 and times steps with the
//! hardware timer, for rp2040js, which has neither the Wi-Fi chip nor a cycle-timed PIO.
//!
//! How the pieces fit:
//! - [`motion`] owns the time-driven side of the [`Controller`]: it polls the core a fixed
//!   lookahead ahead of real time, at each deadline exactly, and turns the steps into
//!   timestamped pin patterns ([`events`]), one queue per axis.
//! - A step back-end per axis plays each queue out at the exact times: PIO state machines
//!   ([`pio_steps`]) on the board, timer-driven GPIO ([`timer_steps`]) in the emulator.
//! - [`link`] serves the protocol on any byte stream (TCP, USB, UART), one session each.
//! - [`watchdog`] resets the board when a main loop stops making progress.

pub mod events;
pub mod link;
mod log;
pub mod motion;
pub mod rng;
pub mod watchdog;

#[cfg(feature = "board")]
pub mod flash;
#[cfg(feature = "board")]
pub mod led;
#[cfg(feature = "board")]
pub mod pio_steps;
#[cfg(feature = "board")]
pub mod scratch;
#[cfg(feature = "board")]
pub mod tcp;
#[cfg(feature = "board")]
pub mod usb;
#[cfg(feature = "board")]
pub mod wifi;

#[cfg(feature = "emu")]
pub mod timer_steps;
#[cfg(feature = "emu")]
pub mod uart;

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use crate::Controller;

/// Axes a board drives (four groups of four GPIOs).
pub const AXES: u8 = 4;

/// Where the record lives: flash on the board, RAM in the emulator (which has no boot ROM
/// for the flash routines).
#[cfg(feature = "board")]
pub type Store = flash::FlashStorage;
#[cfg(not(feature = "board"))]
pub type Store = crate::RamStorage;

/// The firmware core, shared by the motion task (high priority) and the link tasks. The
/// lock is a short critical section: one request, or one poll.
pub type SharedCore = Mutex<CriticalSectionRawMutex, RefCell<Controller<Store>>>;

/// Microseconds since boot, the core's clock.
pub fn now_us() -> u64 {
    embassy_time::Instant::now().as_micros()
}
