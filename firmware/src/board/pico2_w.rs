//! The Raspberry Pi Pico 2 W: an RP2350A (Cortex-M33 at 150 MHz, 520 KiB SRAM, 16 KiB XIP
//! cache, a TRNG), 4 MiB of QSPI flash, and the CYW43439 radio on PIO0. What the shared
//! board image ([`super::image`]) needs to know of it: interrupts, flash geometry, the PIO
//! block that times steps, the radio's SPI clock, the board id and the entropy source.
//!
//! Pins: the Pico header's, which the Pico W shares and the image takes by name: steps on
//! GP2-5, GP6-9, GP10-13, GP14-17; the radio on GP23 (power), GP24 (data), GP25 (select),
//! GP29 (clock).

use embassy_rp::Peri;
use embassy_rp::peripherals::{DMA_CH0, PIO0, PIO1, TRNG, USB};
use embassy_rp::trng::{self, Trng};
use embassy_rp::{bind_interrupts, dma, pio, usb};

use super::flash::BoardFlash;
use super::rng;

/// The board's name in `Identity`.
pub const NAME: &str = "pico2-w";

/// The QSPI flash (W25Q32RV): 4 MiB.
pub const FLASH_SIZE: usize = 4 * 1024 * 1024;

/// The PIO block whose state machines time the steps (PIO0 drives the radio, PIO2 is
/// free).
pub type StepPio = PIO1;

/// The radio's PIO-SPI clock divider: at the RP2350's 150 MHz the driver's default (75 MHz)
/// is too fast for the Pico 2 W's radio module, so 50 MHz, as embassy's Pico 2 W example.
pub use cyw43_pio::RM2_CLOCK_DIVIDER as RADIO_CLOCK_DIVIDER;

/// The alarm interrupt of embassy-time's driver.
pub use embassy_rp::interrupt::TIMER0_IRQ_0 as TIME_IRQ;

bind_interrupts!(pub struct Irqs {
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
    PIO1_IRQ_0 => pio::InterruptHandler<StepPio>;
    DMA_IRQ_0 => dma::InterruptHandler<DMA_CH0>;
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
    TRNG_IRQ => trng::InterruptHandler<TRNG>;
});

/// The board id: the RP2350's 64-bit chip id from OTP (the flash's unique id is not
/// readable through embassy-rp on this chip).
pub fn board_id(_flash: &mut BoardFlash) -> Option<[u8; 8]> {
    embassy_rp::otp::get_chipid().ok().map(u64::to_be_bytes)
}

/// Seeds the nonce generator from the RP2350's true random number generator.
pub fn seed_nonces(trng: Peri<'static, TRNG>) {
    let mut trng = Trng::new(trng, Irqs, trng::Config::default());
    rng::seed(&mut trng);
}
