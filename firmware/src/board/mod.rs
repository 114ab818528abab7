//! The board layer: executes what the firmware core decides, on real pins and links, on
//! a Raspberry Pi chip (feature `rp2040` or `rp235x`).
//!
//! Three images share it, one module per board for what differs ([`this`]). The board
//! image ([`image`], features `pico-w` and `pico2-w`: [`pico_w`], [`pico2_w`]) serves the
//! protocol over TCP on Wi-Fi and over USB CDC-ACM and keeps the record in flash. The
//! emulator image (feature `emu`, RP2040: [`emulator`]) serves it over UART0 for rp2040js,
//! which has neither the Wi-Fi chip nor flash routines. All three time steps the same way.
//!
//! How the pieces fit:
//! - [`motion`] owns the time-driven side of the [`Controller`]: it polls the core a fixed
//!   lookahead ahead of real time, at each deadline exactly, and turns the steps into
//!   timestamped pin patterns ([`events`]).
//! - The step engine ([`pio_steps`]) plays them: one PIO state machine per axis, fed by DMA
//!   from a RAM ring the motion task fills.
//! - [`link`] serves the protocol on any byte stream (TCP, USB, UART), one session each.
//! - [`watchdog`] resets the board when a main loop stops making progress.

#[cfg(all(feature = "rp2040", feature = "rp235x"))]
compile_error!("features `rp2040` and `rp235x` exclude each other: choose one chip");
#[cfg(all(feature = "pico-w", feature = "pico2-w"))]
compile_error!("features `pico-w` and `pico2-w` exclude each other: choose one board");
#[cfg(all(feature = "board", not(any(feature = "pico-w", feature = "pico2-w"))))]
compile_error!("feature `board` needs a board: enable `pico-w` or `pico2-w` instead");
#[cfg(not(any(feature = "board", feature = "emu")))]
compile_error!("a chip feature needs an image: enable `pico-w`, `pico2-w` or `emu`");
#[cfg(all(feature = "board", feature = "emu"))]
compile_error!("features `emu` and the board features exclude each other: choose one image");

pub mod events;
pub mod link;
mod log;
pub mod motion;
pub mod pio_steps;
pub mod rng;
pub mod watchdog;

#[cfg(feature = "board")]
pub mod flash;
#[cfg(feature = "board")]
pub mod image;
#[cfg(feature = "board")]
pub mod led;
#[cfg(feature = "pico2-w")]
pub mod pico2_w;
#[cfg(feature = "pico-w")]
pub mod pico_w;
#[cfg(feature = "board")]
pub mod scratch;
#[cfg(feature = "board")]
pub mod tcp;
#[cfg(feature = "board")]
pub mod usb;
#[cfg(feature = "board")]
pub mod wifi;

#[cfg(feature = "emu")]
pub mod emulator;
#[cfg(feature = "emu")]
pub mod uart;

/// The board this image is built for.
#[cfg(feature = "emu")]
pub use emulator as this;
#[cfg(feature = "pico-w")]
pub use pico_w as this;
#[cfg(feature = "pico2-w")]
pub use pico2_w as this;

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
