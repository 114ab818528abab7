//! The Raspberry Pi Pico W: an RP2040 (Cortex-M0+ at 125 MHz, 264 KiB SRAM, 16 KiB XIP
//! cache), 2 MiB of QSPI flash, and the CYW43439 radio on PIO0. What the shared board image
//! ([`super::image`]) needs to know of it: interrupts, flash geometry, the PIO block that
//! times steps, the radio's SPI clock, the board id and the entropy source.
//!
//! Pins: the Pico header's, which the Pico 2 W shares and the image takes by name: steps on
//! GP2-5, GP6-9, GP10-13, GP14-17; the radio on GP23 (power), GP24 (data), GP25 (select),
//! GP29 (clock).

use embassy_rp::clocks::RoscRng;
use embassy_rp::peripherals::{DMA_CH0, PIO0, PIO1, USB};
use embassy_rp::{bind_interrupts, dma, pio, usb};

use super::flash::BoardFlash;
use super::rng;

/// The board's name in `Identity`.
pub const NAME: &str = "pico-w";

/// The QSPI flash (W25Q16JV): 2 MiB.
pub const FLASH_SIZE: usize = 2 * 1024 * 1024;

/// The PIO block whose state machines time the steps (PIO0 drives the radio).
pub type StepPio = PIO1;

/// The radio's PIO-SPI clock divider: the driver's default, 62.5 MHz at 125 MHz.
pub use cyw43_pio::DEFAULT_CLOCK_DIVIDER as RADIO_CLOCK_DIVIDER;

/// The alarm interrupt of embassy-time's driver.
pub use embassy_rp::interrupt::TIMER_IRQ_0 as TIME_IRQ;

bind_interrupts!(pub struct Irqs {
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
    PIO1_IRQ_0 => pio::InterruptHandler<StepPio>;
    DMA_IRQ_0 => dma::InterruptHandler<DMA_CH0>;
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
});

/// The board id: the flash chip's 64-bit unique id.
pub fn board_id(flash: &mut BoardFlash) -> Option<[u8; 8]> {
    let mut id = [0u8; 8];
    flash.blocking_unique_id(&mut id).ok().map(|()| id)
}

/// Seeds the nonce generator from the ring oscillator, the RP2040's only entropy source.
pub fn seed_nonces() {
    rng::seed(&mut RoscRng);
}
