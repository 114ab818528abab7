//! The board-less image for the rp2040js emulator: the same firmware core, motion task,
//! step engine and protocol as the Pico W image, served on UART0 (GP0 TX, GP1 RX, 115200
//! baud), with steps on the same pins (GP2-5, GP6-9, GP10-13, GP14-17) timed by PIO1 fed by
//! DMA. No Wi-Fi chip, USB, flash or logging: the record lives in RAM.
//!
//! It boots directly from its vector table (the emulator has no boot ROM), and a panic
//! executes `bkpt`, which the emulator harness reports.

#![no_std]
#![no_main]

use core::cell::RefCell;

use embassy_executor::{InterruptExecutor, Spawner};
use embassy_rp::interrupt;
use embassy_rp::interrupt::{InterruptExt, Priority};
use embassy_rp::uart::{BufferedUart, Config};
use embassy_rp::watchdog::Watchdog;
use embassy_sync::blocking_mutex::Mutex;
use optalign_firmware::board::events::EventSink;
use optalign_firmware::board::rng::Nonces;
use optalign_firmware::board::this::{self, Irqs};
use optalign_firmware::board::{AXES, SharedCore, motion, now_us, uart, watchdog};
use optalign_firmware::{BoardInfo, Controller, RamStorage, step_engine};
use optalign_protocol::Capabilities;
use static_cell::StaticCell;

/// Runs the motion task above the UART link.
static MOTION: InterruptExecutor = InterruptExecutor::new();

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
    // As on the board: the alarm that wakes the motion task, then the motion task, then
    // the link.
    this::TIME_IRQ.set_priority(Priority::P0);
    interrupt::SWI_IRQ_1.set_priority(Priority::P1);
    interrupt::UART0_IRQ.set_priority(Priority::P2);

    let info = BoardInfo {
        board: this::NAME,
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

    let motion_spawner = MOTION.start(interrupt::SWI_IRQ_1);
    // Making the engine or spawning fails only on a bug that shows at the first boot.
    let engine = step_engine!(p, p.PIO1, Irqs).unwrap();
    motion_spawner.spawn(motion::run(core, EventSink::new(engine)).unwrap());

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
