//! The board image, one for each board from the same code: the firmware core driving up
//! to four stepper axes, serving the protocol over Wi-Fi (TCP port 7878) and USB serial.
//! What differs between the boards comes from [`super::this`] (the `pico_w` or `pico2_w`
//! module).
//!
//! Two executors: the thread-mode one runs the links, Wi-Fi, flash writes and the
//! watchdog; a high-priority interrupt executor (SWI_IRQ_1) runs the motion task alone,
//! which hands the steps to the PIO state machines through DMA ([`super::pio_steps`]), so
//! no network or USB work can delay a step. Pin map and wiring: `docs/hardware.md`.

use core::cell::RefCell;

use defmt::{info, unwrap, warn};
use embassy_executor::{InterruptExecutor, Spawner};
use embassy_rp::interrupt;
use embassy_rp::interrupt::{InterruptExt, Priority};
use embassy_rp::watchdog::{ResetReason, Watchdog};
use embassy_sync::blocking_mutex::Mutex;
use optalign_protocol::Capabilities;
use static_cell::StaticCell;

use super::events::EventSink;
use super::flash::{BoardFlash, FlashStorage};
use super::rng::Nonces;
use super::this::{self, Irqs};
use super::wifi::Radio;
use super::{AXES, SharedCore, flash, motion, now_us, tcp, usb, watchdog, wifi};
use crate::{BoardInfo, Controller};

/// Runs the motion task above everything in thread mode.
static MOTION: InterruptExecutor = InterruptExecutor::new();

#[interrupt]
unsafe fn SWI_IRQ_1() {
    // SAFETY: only this interrupt polls the executor, after `start`.
    unsafe { MOTION.on_interrupt() }
}

/// Brings the board up and starts every task; returns once the links are served.
pub async fn run(spawner: Spawner) {
    let p = embassy_rp::init(Default::default());
    let mut dog = Watchdog::new(p.WATCHDOG);
    if matches!(dog.reset_reason(), Some(ResetReason::TimedOut)) {
        warn!("restarted by the watchdog");
    }
    dog.pause_on_debug(true);
    dog.start(watchdog::BOOT_TIMEOUT);

    // NVIC priorities, P0 highest: the alarm that wakes the motion task, then the motion
    // task; the links only wake thread mode.
    this::TIME_IRQ.set_priority(Priority::P0);
    interrupt::SWI_IRQ_1.set_priority(Priority::P1);
    interrupt::PIO0_IRQ_0.set_priority(Priority::P2);
    interrupt::USBCTRL_IRQ.set_priority(Priority::P2);

    #[cfg(feature = "pico-w")]
    this::seed_nonces();
    #[cfg(feature = "pico2-w")]
    this::seed_nonces(p.TRNG);

    // The record, before anything moves: the axes come back where they were, coils off.
    let mut board_flash = BoardFlash::new_blocking(p.FLASH);
    let id = this::board_id(&mut board_flash).unwrap_or_else(|| {
        warn!("no board id");
        [0; 8]
    });
    let storage = FlashStorage::new(board_flash);
    let info = BoardInfo {
        board: this::NAME,
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
        "optalign {} on {} {:016x}",
        info.firmware_version, info.board, info.board_id
    );

    // Steps: one state machine per axis, on GP2-5, GP6-9, GP10-13, GP14-17, fed by DMA.
    let motion_spawner = MOTION.start(interrupt::SWI_IRQ_1);
    let engine = unwrap!(crate::step_engine!(p, p.PIO1, Irqs));
    motion_spawner.spawn(unwrap!(motion::run(core, EventSink::new(engine))));

    spawner.spawn(unwrap!(flash::writer(core)));
    spawner.spawn(unwrap!(watchdog::run(dog)));

    static SERIAL: StaticCell<heapless::String<16>> = StaticCell::new();
    let serial = SERIAL.init(hex(&id));
    usb::start(spawner, core, p.USB, Irqs, serial.as_str());

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
