//! The rp2040js emulator's board: an RP2040 with UART0 on GP0/GP1 and the step pins of
//! the Pico header, nothing else. What the emulator image (`src/bin/optalign-emu.rs`) and
//! the step engine need to know of it: its name, interrupts and the PIO block that times
//! steps, the same as on the Pico W.

use embassy_rp::peripherals::{PIO1, UART0};
use embassy_rp::{bind_interrupts, pio, uart};

/// The board's name in `Identity`.
pub const NAME: &str = "rp2040-emulator";

/// The PIO block whose state machines time the steps.
pub type StepPio = PIO1;

/// The alarm interrupt of embassy-time's driver.
pub use embassy_rp::interrupt::TIMER_IRQ_0 as TIME_IRQ;

bind_interrupts!(pub struct Irqs {
    UART0_IRQ => uart::BufferedInterruptHandler<UART0>;
    PIO1_IRQ_0 => pio::InterruptHandler<StepPio>;
});
