//! Flashing a board without a debug probe: the firmware ELF becomes a UF2 image that the
//! chip's boot loader (the RPI-RP2 USB drive of an RP2040, the RP2350 drive of an RP2350)
//! writes to flash.
//!
//! The converter is our own (an ELF program-header reader and a UF2 writer, ~150 lines)
//! rather than a dependency: it needs only the loadable segments of one kind of ELF.

pub mod drive;
pub mod elf;
pub mod uf2;

use anyhow::Context;
use std::path::Path;

/// The boards a firmware image is built for.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Board {
    /// Raspberry Pi Pico W (RP2040).
    #[value(name = "pico-w")]
    PicoW,
    /// Raspberry Pi Pico 2 W (RP2350A, Arm cores).
    #[value(name = "pico2w")]
    Pico2W,
}

impl Board {
    /// The board's name as in the docs.
    pub fn name(self) -> &'static str {
        match self {
            Self::PicoW => "Pico W",
            Self::Pico2W => "Pico 2 W",
        }
    }

    /// The firmware binary's name (firmware/src/bin/).
    pub fn binary(self) -> &'static str {
        match self {
            Self::PicoW => "optalign-pico-w",
            Self::Pico2W => "optalign-pico2-w",
        }
    }

    /// The firmware crate's feature that builds this board's image.
    pub fn feature(self) -> &'static str {
        match self {
            Self::PicoW => "pico-w",
            Self::Pico2W => "pico2-w",
        }
    }

    /// The Rust target the image is built for.
    pub fn target(self) -> &'static str {
        match self {
            Self::PicoW => "thumbv6m-none-eabi",
            Self::Pico2W => "thumbv8m.main-none-eabihf",
        }
    }

    /// The UF2 family id the chip's boot loader accepts.
    pub fn family_id(self) -> u32 {
        match self {
            Self::PicoW => uf2::RP2040_FAMILY_ID,
            Self::Pico2W => uf2::RP2350_ARM_S_FAMILY_ID,
        }
    }

    /// What the chip's boot loader drive says in `INFO_UF2.TXT`'s `Board-ID:` line.
    pub fn boot_drive_id(self) -> &'static str {
        match self {
            Self::PicoW => "RPI-RP2",
            Self::Pico2W => "RP2350",
        }
    }
}

/// Reads the firmware ELF at `path` and encodes it as a UF2 image for `board`'s flash.
pub fn uf2_from_elf(path: &Path, board: Board) -> anyhow::Result<Vec<u8>> {
    let file =
        std::fs::read(path).with_context(|| format!("reading firmware {}", path.display()))?;
    let segments =
        elf::load_segments(&file).with_context(|| format!("reading ELF {}", path.display()))?;
    uf2::encode(&segments, board.family_id())
        .with_context(|| format!("converting {}", path.display()))
}
