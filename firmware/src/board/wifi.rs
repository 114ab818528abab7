//! Wi-Fi: the CYW43439 over PIO-SPI, the network stack with DHCP, and the supervisor that
//! keeps the board on the network with the credentials stored in the record.
//!
//! The supervisor joins, waits for a DHCP lease, and watches for link loss or newly
//! provisioned credentials; a failed join or lease is retried after an exponential
//! back-off (1 s doubling to 60 s, reset by success). It owns the chip's control handle
//! and so also drives the status LED ([`super::led`]) while it waits.
//!
//! The Wi-Fi firmware and CLM come from the `cyw43-firmware` crate; the board nvram is
//! embedded from the file `build.rs` found (`OPTALIGN_CYW43_NVRAM`).

use cyw43::{A4, Aligned, Control, JoinOptions, PowerManagementMode};
use cyw43_pio::PioSpi;
use defmt::unwrap;
use embassy_executor::Spawner;
use embassy_futures::select::{Either, select};
use embassy_net::{Config, DhcpConfig, Stack, StackResources};
use embassy_rp::gpio::{Level, Output};
use embassy_rp::peripherals::{DMA_CH0, PIN_23, PIN_24, PIN_25, PIN_29, PIO0};
use embassy_rp::pio::{InterruptHandler, Pio};
use embassy_rp::{Peri, dma, interrupt};
use embassy_time::{Duration, Timer, with_timeout};
use static_cell::StaticCell;

use super::log::{info, warn};
use super::rng::Nonces;
use super::{SharedCore, led, tcp, this};
use crate::record::WifiCredentials;
use crate::session::RngSource;

/// CYW43439 Wi-Fi firmware (~226 KiB), 4-byte aligned as the driver streams words.
static FIRMWARE: &Aligned<A4, [u8]> = &Aligned(*cyw43_firmware::CYW43_43439A0);
/// CYW43439 country locale matrix.
static CLM: &[u8] = cyw43_firmware::CYW43_43439A0_CLM;
/// Board nvram (radio parameters; the Pico 2 W uses the Pico W's).
static NVRAM: &Aligned<A4, [u8]> = &Aligned(*include_bytes!(env!("OPTALIGN_CYW43_NVRAM_PATH")));

/// How long a DHCP lease may take after joining.
const DHCP_TIMEOUT: Duration = Duration::from_secs(30);
const BACKOFF_MIN: Duration = Duration::from_secs(1);
const BACKOFF_MAX: Duration = Duration::from_secs(60);
/// How often the stored credentials are checked for a change.
const CREDENTIALS_POLL: Duration = Duration::from_secs(1);
/// Sockets: DHCP plus the TCP sessions.
const SOCKETS: usize = 1 + tcp::SESSIONS;

/// The fixed wiring of the CYW43439 (the same on the Pico W and the Pico 2 W).
pub struct Radio {
    pub power: Peri<'static, PIN_23>,
    pub data: Peri<'static, PIN_24>,
    pub select: Peri<'static, PIN_25>,
    pub clock: Peri<'static, PIN_29>,
    pub pio: Peri<'static, PIO0>,
    pub dma: Peri<'static, DMA_CH0>,
}

type Runner = cyw43::Runner<'static, cyw43::SpiBus<Output<'static>, PioSpi<'static, PIO0, 0>>>;

#[embassy_executor::task]
async fn chip(runner: Runner) -> ! {
    runner.run().await
}

#[embassy_executor::task]
async fn stack_runner(mut runner: embassy_net::Runner<'static, cyw43::NetDriver<'static>>) -> ! {
    runner.run().await
}

/// Powers the radio up, loads its firmware and starts the network stack (DHCP, asking
/// for `hostname`, which routers list with the lease).
pub async fn start<I>(
    spawner: Spawner,
    radio: Radio,
    irqs: I,
    hostname: &str,
) -> (Stack<'static>, Control<'static>)
where
    I: interrupt::typelevel::Binding<interrupt::typelevel::PIO0_IRQ_0, InterruptHandler<PIO0>>
        + interrupt::typelevel::Binding<
            interrupt::typelevel::DMA_IRQ_0,
            dma::InterruptHandler<DMA_CH0>,
        > + Copy
        + 'static,
{
    let power = Output::new(radio.power, Level::Low);
    let select = Output::new(radio.select, Level::High);
    let mut pio = Pio::new(radio.pio, irqs);
    let spi = PioSpi::new(
        &mut pio.common,
        pio.sm0,
        this::RADIO_CLOCK_DIVIDER,
        pio.irq0,
        select,
        radio.data,
        radio.clock,
        dma::Channel::new(radio.dma, irqs),
    );
    static STATE: StaticCell<cyw43::State> = StaticCell::new();
    let (device, mut control, runner) =
        cyw43::new(STATE.init(cyw43::State::new()), power, spi, FIRMWARE, NVRAM).await;
    spawner.spawn(unwrap!(chip(runner)));
    control.init(CLM).await;
    // Power saving adds tens of milliseconds to every incoming packet.
    control
        .set_power_management(PowerManagementMode::None)
        .await;
    let mut dhcp = DhcpConfig::default();
    dhcp.hostname = hostname.try_into().ok();
    static RESOURCES: StaticCell<StackResources<SOCKETS>> = StaticCell::new();
    // The stack's seed (TCP initial sequence numbers, local ports) from the whitened
    // generator, not raw ring-oscillator bits.
    let mut seed = [0u8; 8];
    Nonces.fill(&mut seed);
    let (stack, runner) = embassy_net::new(
        device,
        Config::dhcpv4(dhcp),
        RESOURCES.init(StackResources::new()),
        u64::from_le_bytes(seed),
    );
    spawner.spawn(unwrap!(stack_runner(runner)));
    (stack, control)
}

/// Keeps the board on the network with the stored credentials.
#[embassy_executor::task]
pub async fn supervise(
    core: &'static SharedCore,
    mut control: Control<'static>,
    stack: Stack<'static>,
) -> ! {
    let mut backoff = BACKOFF_MIN;
    loop {
        let Some(credentials) = stored(core) else {
            info!("wifi: no credentials; provision them over USB");
            select(led::show(&mut control, false), changed(core, None)).await;
            continue;
        };
        info!("wifi: joining {}", credentials.ssid.as_str());
        let options = if credentials.passphrase.is_empty() {
            JoinOptions::new_open()
        } else {
            JoinOptions::new(credentials.passphrase.as_bytes())
        };
        let joined = match control.join(&credentials.ssid, options).await {
            Ok(()) => {
                let lease = with_timeout(DHCP_TIMEOUT, stack.wait_config_up());
                let waited = select(led::show(&mut control, false), lease).await;
                matches!(waited, Either::Second(Ok(())))
            }
            Err(error) => {
                warn!("wifi: join failed: {}", error);
                false
            }
        };
        if !joined {
            warn!("wifi: retrying in {} s", backoff.as_secs());
            control.leave().await;
            let wait = select(Timer::after(backoff), changed(core, Some(&credentials)));
            select(led::show(&mut control, false), wait).await;
            backoff = (backoff * 2).min(BACKOFF_MAX);
            continue;
        }
        backoff = BACKOFF_MIN;
        if let Some(config) = stack.config_v4() {
            info!(
                "wifi: up at {}, protocol on TCP port {}",
                config.address,
                tcp::PORT
            );
        }
        let lost = select(stack.wait_link_down(), changed(core, Some(&credentials)));
        select(led::show(&mut control, true), lost).await;
        warn!("wifi: link lost or credentials changed; rejoining");
        control.leave().await;
    }
}

/// The credentials in the record.
fn stored(core: &SharedCore) -> Option<WifiCredentials> {
    core.lock(|cell| cell.borrow().wifi().cloned())
}

/// Returns once the stored credentials differ from `current`.
async fn changed(core: &SharedCore, current: Option<&WifiCredentials>) {
    while stored(core).as_ref() == current {
        Timer::after(CREDENTIALS_POLL).await;
    }
}
