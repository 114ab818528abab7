//! USB CDC-ACM serial serving the protocol: the trusted link, for provisioning Wi-Fi and
//! the access key, and for bench use without Wi-Fi.
//!
//! The device enumerates as Raspberry Pi's CDC serial (VID 0x2E8A, PID 0x000A, as the
//! Pico SDK's stdio does), named "optalign motor controller", with the flash's unique id
//! as serial number, so `/dev/serial/by-id/` tells boards apart.

use embassy_rp::Peri;
use embassy_rp::interrupt::typelevel::{Binding, USBCTRL_IRQ};
use embassy_rp::peripherals::USB;
use embassy_rp::usb::{Driver, InterruptHandler};
use embassy_usb::class::cdc_acm::{CdcAcmClass, CdcAcmError, Sender, State};
use embassy_usb::driver::EndpointError;
use embassy_usb::{Builder, UsbDevice};
use embedded_io_async::{ErrorType, Write};
use static_cell::StaticCell;

use super::link;
use super::{SharedCore, now_us};
use crate::connection::Connection;

const VID: u16 = 0x2E8A;
const PID: u16 = 0x000A;
const PACKET: usize = 64;

type UsbDriver = Driver<'static, USB>;

#[embassy_executor::task]
async fn device(mut device: UsbDevice<'static, UsbDriver>) -> ! {
    device.run().await
}

/// Starts the USB device and the serial session.
pub fn start(
    spawner: embassy_executor::Spawner,
    core: &'static SharedCore,
    usb: Peri<'static, USB>,
    irqs: impl Binding<USBCTRL_IRQ, InterruptHandler<USB>>,
    serial_number: &'static str,
) {
    let mut config = embassy_usb::Config::new(VID, PID);
    config.manufacturer = Some("optalign");
    config.product = Some("optalign motor controller");
    config.serial_number = Some(serial_number);
    config.max_power = 100;
    config.max_packet_size_0 = 64;

    static CONFIG: StaticCell<[u8; 256]> = StaticCell::new();
    static BOS: StaticCell<[u8; 256]> = StaticCell::new();
    static CONTROL: StaticCell<[u8; 64]> = StaticCell::new();
    static CDC: StaticCell<State> = StaticCell::new();
    let mut builder = Builder::new(
        Driver::new(usb, irqs),
        config,
        CONFIG.init([0; 256]),
        BOS.init([0; 256]),
        &mut [],
        CONTROL.init([0; 64]),
    );
    let class = CdcAcmClass::new(&mut builder, CDC.init(State::new()), PACKET as u16);
    spawner.spawn(defmt::unwrap!(device(builder.build())));
    spawner.spawn(defmt::unwrap!(serial(core, class)));
}

#[embassy_executor::task]
async fn serial(core: &'static SharedCore, class: CdcAcmClass<'static, UsbDriver>) -> ! {
    static RX: StaticCell<[u8; PACKET]> = StaticCell::new();
    let (sender, receiver) = class.split();
    let mut rx = receiver.into_buffered(RX.init([0; PACKET]));
    let mut tx = Packets(sender);
    loop {
        rx.wait_connection().await;
        let connection = Connection::serial(now_us());
        link::serve(core, connection, &mut rx, &mut tx, None).await;
    }
}

/// Writes each buffer as USB packets, ending a transfer that fills its last packet with a
/// zero-length packet so the host does not wait for more.
struct Packets(Sender<'static, UsbDriver>);

impl ErrorType for Packets {
    type Error = CdcAcmError;
}

impl Write for Packets {
    async fn write(&mut self, buf: &[u8]) -> Result<usize, CdcAcmError> {
        for packet in buf.chunks(PACKET) {
            send(&mut self.0, packet).await?;
        }
        if !buf.is_empty() && buf.len().is_multiple_of(PACKET) {
            send(&mut self.0, &[]).await?;
        }
        Ok(buf.len())
    }

    async fn flush(&mut self) -> Result<(), CdcAcmError> {
        Ok(())
    }
}

async fn send(sender: &mut Sender<'static, UsbDriver>, packet: &[u8]) -> Result<(), CdcAcmError> {
    sender
        .write_packet(packet)
        .await
        .map_err(|_: EndpointError| CdcAcmError::NotConnected)
}
