//! The protocol on UART0 (GP0 TX, GP1 RX, 115200 8N1), the emulator image's only link. It
//! counts as the trusted serial link, as USB does on the board.

use embassy_rp::uart::BufferedUart;

use super::link;
use super::{SharedCore, now_us};
use crate::connection::Connection;

pub const BAUD: u32 = 115_200;

/// Serves the protocol on `uart`, a new session each time the stream fails.
#[embassy_executor::task]
pub async fn serve(core: &'static SharedCore, uart: BufferedUart) -> ! {
    let (mut tx, mut rx) = uart.split();
    loop {
        let connection = Connection::serial(now_us());
        link::serve(core, connection, &mut rx, &mut tx, None).await;
    }
}
