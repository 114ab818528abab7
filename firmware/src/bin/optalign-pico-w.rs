//! The Raspberry Pi Pico W image: the firmware core driving up to four stepper axes,
//! serving the protocol over Wi-Fi (TCP port 7878) and USB serial.
//!
//! Two executors: the thread-mode one runs the links, Wi-Fi, flash writes and the
//! watchdog; a high-priority interrupt executor (SWI_IRQ_1) runs the motion task and the
//! PIO feeders, so no network or USB work can delay a step. Pin map and wiring:
//! `docs/hardware.md`.

#![no_std]
#![no_main]

use core::cell::RefCell;

use defmt::{info, unwrap, warn};
use embassy_executor::{InterruptExecutor, Spawner};
use embassy_rp::interrupt;
use embassy_rp::interrupt::{InterruptExt, Priority};
use embassy_rp::peripherals::{DMA_CH0, PIO0, PIO1, USB};
use embassy_rp::watchdog::{ResetReason, Watchdog};
use embassy_rp::{bind_interrupts, dma, pio, usb};
use embassy_sync::blocking_mutex::Mutex;
use optalign_firmware::board::events::QUEUES;
use optalign_firmware::board::flash::{BoardFlash, FlashStorage};
use optalign_firmware::board::pio_steps::{Feeder, StepProgram};
use optalign_firmware::board::rng::Nonces;
use optalign_firmware::board::wifi::Radio;
use optalign_firmware::board::{
    AXES, SharedCore, flash, motion, now_us, tcp, usb as usb_link, watchdog, wifi,
};
use optalign_firmware::{BoardInfo, Controller};
use optalign_protocol::Capabilities;
use static_cell::StaticCell;
use {defmt_rtt as _, panic_probe as _};

bind_interrupts!(struct Irqs {
    PIO0_IRQ_0 => pio::InterruptHandler<PIO0>;
    PIO1_IRQ_0 => pio::InterruptHandler<PIO1>;
    DMA_IRQ_0 => dma::InterruptHandler<DMA_CH0>;
    USBCTRL_IRQ => usb::InterruptHandler<USB>;
});

/// Runs the motion task and the step feeders above everything in thread mode.
static MOTION: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
unsafe fn SWI_IRQ_1() {
    // SAFETY: only this interrupt polls the executor, after `start`.
    unsafe { MOTION.on_interrupt() }
}

#[embassy_executor::task]
async fn axis0(feeder: Feeder<'static, 0>) -> ! {
    feeder.run().await
}

#[embassy_executor::task]
async fn axis1(feeder: Feeder<'static, 1>) -> ! {
    feeder.run().await
}

#[embassy_executor::task]
async fn axis2(feeder: Feeder<'static, 2>) -> ! {
    feeder.run().await
}

#[embassy_executor::task]
async fn axis3(feeder: Feeder<'static, 3>) -> ! {
    feeder.run().await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());
    let mut dog = Watchdog::new(p.WATCHDOG);
    if matches!(dog.reset_reason(), Some(ResetReason::TimedOut)) {
        warn!("restarted by the watchdog");
    }
    dog.pause_on_debug(true);
    dog.start(watchdog::BOOT_TIMEOUT);

    // NVIC priorities, P0 highest: step timing first; the links only wake thread mode.
    interrupt::TIMER_IRQ_0.set_priority(Priority::P0);
    interrupt::PIO1_IRQ_0.set_priority(Priority::P0);
    interrupt::SWI_IRQ_1.set_priority(Priority::P1);
    interrupt::PIO0_IRQ_0.set_priority(Priority::P2);
    interrupt::USBCTRL_IRQ.set_priority(Priority::P2);

    // The record, before anything moves: the axes come back where they were, coils off.
    let mut board_flash = BoardFlash::new_blocking(p.FLASH);
    let mut id = [0u8; 8];
    if board_flash.blocking_unique_id(&mut id).is_err() {
        warn!("flash: no unique id");
    }
    let storage = FlashStorage::load(board_flash);
    let info = BoardInfo {
        board: "pico-w",
        firmware_version: env!("CARGO_PKG_VERSION"),
        board_id: u64::from_be_bytes(id),
        axes: AXES,
        capabilities: Capabilities::UNIPOLAR_HALF_STEP
            | Capabilities::STEP_DIR
            | Capabilities::PERSISTENCE
            | Capabilities::WIFI
            | Capabilities::SERIAL,
    };
    static CORE: StaticCell<SharedCore> = StaticCell::new();
    let core: &'static SharedCore = CORE.init(Mutex::new(RefCell::new(Controller::new(
        info,
        storage,
        now_us(),
        &mut Nonces,
    ))));
    info!(
        "optalign {} on board {:016x}",
        info.firmware_version, info.board_id
    );

    // Steps: one PIO1 state machine per axis, on GP2-5, GP6-9, GP10-13, GP14-17.
    let motion_spawner = MOTION.start(interrupt::SWI_IRQ_1);
    let pio::Pio {
        mut common,
        sm0,
        sm1,
        sm2,
        sm3,
        ..
    } = pio::Pio::new(p.PIO1, Irqs);
    let program = StepProgram::load(&mut common);
    let pins0 = [
        common.make_pio_pin(p.PIN_2),
        common.make_pio_pin(p.PIN_3),
        common.make_pio_pin(p.PIN_4),
        common.make_pio_pin(p.PIN_5),
    ];
    let pins1 = [
        common.make_pio_pin(p.PIN_6),
        common.make_pio_pin(p.PIN_7),
        common.make_pio_pin(p.PIN_8),
        common.make_pio_pin(p.PIN_9),
    ];
    let pins2 = [
        common.make_pio_pin(p.PIN_10),
        common.make_pio_pin(p.PIN_11),
        common.make_pio_pin(p.PIN_12),
        common.make_pio_pin(p.PIN_13),
    ];
    let pins3 = [
        common.make_pio_pin(p.PIN_14),
        common.make_pio_pin(p.PIN_15),
        common.make_pio_pin(p.PIN_16),
        common.make_pio_pin(p.PIN_17),
    ];
    let [q0, q1, q2, q3] = &QUEUES;
    motion_spawner.spawn(unwrap!(axis0(Feeder::new(sm0, &program, pins0, q0))));
    motion_spawner.spawn(unwrap!(axis1(Feeder::new(sm1, &program, pins1, q1))));
    motion_spawner.spawn(unwrap!(axis2(Feeder::new(sm2, &program, pins2, q2))));
    motion_spawner.spawn(unwrap!(axis3(Feeder::new(sm3, &program, pins3, q3))));
    motion_spawner.spawn(unwrap!(motion::run(core)));

    spawner.spawn(unwrap!(flash::writer(core)));
    spawner.spawn(unwrap!(watchdog::run(dog)));

    static SERIAL: StaticCell<heapless::String<16>> = StaticCell::new();
    let serial = SERIAL.init(hex(&id));
    usb_link::start(spawner, core, p.USB, Irqs, serial.as_str());

    let radio = Radio {
        power: p.PIN_23,
        data: p.PIN_24,
        select: p.PIN_25,
        clock: p.PIN_29,
        pio: p.PIO0,
        dma: p.DMA_CH0,
    };
    let mut hostname: heapless::String<16> = heapless::String::new();
    let _ = hostname.push_str("optalign-");
    let _ = hostname.push_str(serial.get(10..).unwrap_or_default());
    info!("DHCP host name {}", hostname.as_str());
    let (stack, control) = wifi::start(spawner, radio, Irqs, &hostname).await;
    spawner.spawn(unwrap!(wifi::supervise(core, control, stack)));
    for _ in 0..tcp::SESSIONS {
        spawner.spawn(unwrap!(tcp::serve(core, stack)));
    }
    info!("up: USB serial, Wi-Fi, TCP port {}", tcp::PORT);
}

/// `bytes` as lowercase hex.
fn hex(bytes: &[u8; 8]) -> heapless::String<16> {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut out = heapless::String::new();
    for &byte in bytes {
        for nibble in [byte >> 4, byte & 0xF] {
            let _ = out.push(char::from(DIGITS[usize::from(nibble)]));
        }
    }
    out
}
