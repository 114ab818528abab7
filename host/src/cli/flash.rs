//! `optalign flash`: the firmware image as UF2, copied onto a board in BOOTSEL mode.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;

use crate::flash::{drive, uf2, uf2_from_elf};

/// The board image's binary name (firmware/src/bin/).
const BOARD_BIN: &str = "optalign-pico-w";

#[derive(Debug, Args)]
pub struct FlashArgs {
    /// Firmware ELF [default: $CARGO_TARGET_DIR or target, then
    /// thumbv6m-none-eabi/release/optalign-pico-w].
    #[arg(long, value_name = "FILE")]
    elf: Option<PathBuf>,
    /// Also write the UF2 image to this file.
    #[arg(long, value_name = "FILE")]
    uf2_out: Option<PathBuf>,
}

pub fn run(args: FlashArgs) -> anyhow::Result<()> {
    let elf = args.elf.unwrap_or_else(default_elf);
    if !elf.exists() {
        bail!(
            "no firmware at {}: build it with `cargo build --release -p optalign-firmware \
             --features board --target thumbv6m-none-eabi` (or give --elf)",
            elf.display()
        );
    }
    let image = uf2_from_elf(&elf)?;
    let blocks = image.len() / uf2::BLOCK_LEN;
    if let Some(out) = &args.uf2_out {
        write(out, &image)?;
        crate::say!("wrote {} ({blocks} UF2 blocks)", out.display());
    }
    let drives = drive::find_rp2040_drives();
    match drives.as_slice() {
        [drive] => {
            let name = elf.file_stem().unwrap_or(BOARD_BIN.as_ref());
            let target = drive.join(name).with_extension("uf2");
            write(&target, &image)?;
            crate::say!(
                "flashed {} ({blocks} UF2 blocks) through {}: the board reboots into the new firmware",
                elf.display(),
                drive.display()
            );
        }
        [] => {
            let out = match args.uf2_out {
                Some(out) => out,
                None => {
                    let out = elf.with_extension("uf2");
                    write(&out, &image)?;
                    out
                }
            };
            crate::say!(
                "no RPI-RP2 drive is mounted. Hold BOOTSEL while plugging the Pico W into USB, \
                 then copy {} onto the RPI-RP2 drive (or run `optalign flash` again).",
                out.display()
            );
        }
        several => bail!(
            "{} RPI-RP2 drives are mounted ({}): leave one board in BOOTSEL mode, \
             or write the image with --uf2-out and copy it by hand",
            several.len(),
            several
                .iter()
                .map(|d| d.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
    Ok(())
}

fn default_elf() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR").unwrap_or_else(|| "target".into());
    Path::new(&target)
        .join("thumbv6m-none-eabi")
        .join("release")
        .join(BOARD_BIN)
}

fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}
