//! Flashing a board without a debug probe: the firmware ELF becomes a UF2 image that the
//! RP2040 boot loader (the RPI-RP2 USB drive) writes to flash.
//!
//! The converter is our own (an ELF program-header reader and a UF2 writer, ~150 lines)
//! rather than a dependency: it needs only the loadable segments of one kind of ELF.

pub mod drive;
pub mod elf;
pub mod uf2;

use anyhow::Context;
use std::path::Path;

/// Reads the firmware ELF at `path` and encodes it as a UF2 image for the RP2040 flash.
pub fn uf2_from_elf(path: &Path) -> anyhow::Result<Vec<u8>> {
    let file =
        std::fs::read(path).with_context(|| format!("reading firmware {}", path.display()))?;
    let segments =
        elf::load_segments(&file).with_context(|| format!("reading ELF {}", path.display()))?;
    uf2::encode(&segments).with_context(|| format!("converting {}", path.display()))
}
