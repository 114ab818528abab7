//! The Raspberry Pi Pico W image (RP2040): the board image of `optalign_firmware::board::image`
//! with the `pico_w` board module.

#![no_std]
#![no_main]

use {defmt_rtt as _, panic_probe as _};

#[embassy_executor::main]
async fn main(spawner: embassy_executor::Spawner) {
    optalign_firmware::board::image::run(spawner).await
}
