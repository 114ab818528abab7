//! The board-less image for the rp2040js emulator: the same firmware core, motion task
//! and protocol as the Pico W image, served on UART0 (GP0 TX, GP1 RX, 115200 baud), with
//! steps on the same pins (GP2-5, GP6-9, GP10-13, GP14-17) timed by the hardware timer.
//! No Wi-Fi chip, USB, flash or logging: the record lives in RAM.
//!
//! It boots directly from its vector table (the emulator has no boot ROM), and a panic
//! executes `bkpt`, which the emulator harness reports.

#![no_std]
#![no_main]

use core::cell::RefCell;

use embassy_executor::{InterruptExecutor, Spawner};
use embassy_rp::gpio::{AnyPin, Level, Output};
use embassy_rp::interrupt;
use embassy_rp::interrupt::{InterruptExt, Priority};
use embassy_rp::peripherals::UART0;
use embassy_rp::uart::{BufferedInterruptHandler, BufferedUart, Config};
use embassy_rp::watchdog::Watchdog;
use embassy_rp::{Peri, bind_interrupts};
use embassy_sync::blocking_mutex::Mutex;
use optalign_firmware::board::events::QUEUES;
use optalign_firmware::board::rng::Nonces;
use optalign_firmware::board::{AXES, SharedCore, motion, now_us, timer_steps, uart, watchdog};
use optalign_firmware::{BoardInfo, Controller, RamStorage};
use optalign_protocol::Capabilities;
use static_cell::StaticCell;

bind_interrupts!(struct Irqs {
    UART0_IRQ => BufferedInterruptHandler<UART0>;
});

/// Runs the step tasks above everything else, so only a critical section can delay an
/// edge (the board needs no such executor: its PIO times the edges).
static STEPS: InterruptExecutor = InterruptExecutor::new();

/// Runs the motion task above the UART link.
static MOTION: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
unsafe fn SWI_IRQ_0() {
    // SAFETY: only this interrupt polls the executor, after `start`.
    unsafe { STEPS.on_interrupt() }
}

#[interrupt]
unsafe fn SWI_IRQ_1() {
    // SAFETY: only this interrupt polls the executor, after `start`.
    unsafe { MOTION.on_interrupt() }
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());
    let mut dog = Watchdog::new(p.WATCHDOG);
    dog.start(watchdog::BOOT_TIMEOUT);
    interrupt::TIMER_IRQ_0.set_priority(Priority::P0);
    interrupt::SWI_IRQ_0.set_priority(Priority::P0);
    interrupt::SWI_IRQ_1.set_priority(Priority::P1);
    interrupt::UART0_IRQ.set_priority(Priority::P2);

    let info = BoardInfo {
        board: "rp2040-emulator",
        firmware_version: env!("CARGO_PKG_VERSION"),
        board_id: 0x0E30_2040,
        axes: AXES,
        capabilities: Capabilities::UNIPOLAR_HALF_STEP
            | Capabilities::STEP_DIR
            | Capabilities::SERIAL,
    };
    static CORE: StaticCell<SharedCore> = StaticCell::new();
    let core: &'static SharedCore = CORE.init(Mutex::new(RefCell::new(Controller::new(
        info,
        RamStorage::new(),
        now_us(),
        &mut Nonces,
    ))));

    let steps_spawner = STEPS.start(interrupt::SWI_IRQ_0);
    let motion_spawner = MOTION.start(interrupt::SWI_IRQ_1);
    let out = |pin: Peri<'static, AnyPin>| Output::new(pin, Level::Low);
    let [q0, q1, q2, q3] = &QUEUES;
    let axes = [
        (
            q0,
            [
                out(p.PIN_2.into()),
                out(p.PIN_3.into()),
                out(p.PIN_4.into()),
                out(p.PIN_5.into()),
            ],
        ),
        (
            q1,
            [
                out(p.PIN_6.into()),
                out(p.PIN_7.into()),
                out(p.PIN_8.into()),
                out(p.PIN_9.into()),
            ],
        ),
        (
            q2,
            [
                out(p.PIN_10.into()),
                out(p.PIN_11.into()),
                out(p.PIN_12.into()),
                out(p.PIN_13.into()),
            ],
        ),
        (
            q3,
            [
                out(p.PIN_14.into()),
                out(p.PIN_15.into()),
                out(p.PIN_16.into()),
                out(p.PIN_17.into()),
            ],
        ),
    ];
    // Spawning fails only if a task pool is too small: a bug that shows at the first boot.
    for (queue, pins) in axes {
        steps_spawner.spawn(timer_steps::run(queue, pins).unwrap());
    }
    motion_spawner.spawn(motion::run(core).unwrap());

    static TX: StaticCell<[u8; 1024]> = StaticCell::new();
    static RX: StaticCell<[u8; 256]> = StaticCell::new();
    let mut config = Config::default();
    config.baudrate = uart::BAUD;
    let link = BufferedUart::new(
        p.UART0,
        p.PIN_0,
        p.PIN_1,
        Irqs,
        TX.init([0; 1024]),
        RX.init([0; 256]),
        config,
    );
    spawner.spawn(uart::serve(core, link).unwrap());
    spawner.spawn(watchdog::run(dog).unwrap());
}

#[panic_handler]
fn panic(_: &core::panic::PanicInfo) -> ! {
    loop {
        cortex_m::asm::bkpt();
    }
}
