//! `optalign flash`: the firmware image as UF2, copied onto a board in BOOTSEL mode.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;

use crate::flash::{Board, drive, uf2, uf2_from_elf};

#[derive(Debug, Args)]
pub struct FlashArgs {
    /// The board: its image, UF2 family id and boot drive.
    #[arg(long, value_enum, default_value = "pico-w")]
    board: Board,
    /// Firmware ELF [default: $CARGO_TARGET_DIR or target, then the board's
    /// TARGET/release/BINARY: thumbv6m-none-eabi/release/optalign-pico-w for the Pico W,
    /// thumbv8m.main-none-eabihf/release/optalign-pico2-w for the Pico 2 W].
    #[arg(long, value_name = "FILE")]
    elf: Option<PathBuf>,
    /// Also write the UF2 image to this file.
    #[arg(long, value_name = "FILE")]
    uf2_out: Option<PathBuf>,
}

pub fn run(args: FlashArgs) -> anyhow::Result<()> {
    run_with(args, drive::find_boot_drives)
}

/// [`run`], with the mounted boot drives of a board's chip found by `find_drives`.
fn run_with(args: FlashArgs, find_drives: impl Fn(&str) -> Vec<PathBuf>) -> anyhow::Result<()> {
    let board = args.board;
    let elf = args.elf.unwrap_or_else(|| default_elf(board));
    if !elf.exists() {
        bail!(
            "no firmware at {}: build it with `cargo build --release -p optalign-firmware \
             --features {} --target {}` (or give --elf)",
            elf.display(),
            board.feature(),
            board.target()
        );
    }
    let image = uf2_from_elf(&elf, board)?;
    let blocks = image.len() / uf2::BLOCK_LEN;
    if let Some(out) = &args.uf2_out {
        write(out, &image)?;
        crate::say!(
            "wrote {} ({blocks} UF2 blocks for the {}, family id {:#010x})",
            out.display(),
            board.name(),
            board.family_id()
        );
    }
    let label = board.boot_drive_id();
    let drives = find_drives(label);
    match drives.as_slice() {
        [drive] => {
            let name = elf.file_stem().unwrap_or(board.binary().as_ref());
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
                "no {label} drive is mounted. Hold BOOTSEL while plugging the {} into USB, \
                 then copy {} onto the {label} drive (or run `optalign flash` again).",
                board.name(),
                out.display()
            );
        }
        several => bail!(
            "{} {label} drives are mounted ({}): leave one board in BOOTSEL mode, \
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

fn default_elf(board: Board) -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR").unwrap_or_else(|| "target".into());
    Path::new(&target)
        .join(board.target())
        .join("release")
        .join(board.binary())
}

fn write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    std::fs::write(path, bytes).with_context(|| format!("writing {}", path.display()))
}

#[cfg(test)]
mod tests {
    use clap::Parser;

    use super::*;
    use crate::flash::elf::build::{Program, elf};

    #[derive(Debug, Parser)]
    struct Command {
        #[command(flatten)]
        args: FlashArgs,
    }

    /// A firmware ELF with 700 bytes of code at the start of flash.
    fn firmware(dir: &Path) -> PathBuf {
        let code: Vec<u8> = (0..700u32).map(|i| (i % 253) as u8).collect();
        let path = dir.join("firmware.elf");
        let file = elf(&[Program {
            kind: 1,
            paddr: 0x1000_0000,
            vaddr: 0x1000_0000,
            data: &code,
            mem_size: 700,
        }]);
        std::fs::write(&path, file).unwrap();
        path
    }

    fn families(uf2: &[u8]) -> Vec<u32> {
        uf2.chunks(uf2::BLOCK_LEN)
            .map(|block| u32::from_le_bytes(block[28..32].try_into().unwrap()))
            .collect()
    }

    fn parse(words: &[&str]) -> FlashArgs {
        Command::try_parse_from(std::iter::once("flash").chain(words.iter().copied()))
            .unwrap()
            .args
    }

    #[test]
    fn pico2w_writes_blocks_with_the_rp2350_family_id() {
        let dir = tempfile::tempdir().unwrap();
        let elf = firmware(dir.path());
        let out = dir.path().join("image.uf2");
        let args = parse(&[
            "--board",
            "pico2w",
            "--elf",
            elf.to_str().unwrap(),
            "--uf2-out",
            out.to_str().unwrap(),
        ]);
        let asked = std::cell::RefCell::new(Vec::new());
        run_with(args, |label| {
            asked.borrow_mut().push(label.to_owned());
            Vec::new()
        })
        .unwrap();
        assert_eq!(asked.into_inner(), ["RP2350"], "looks for the RP2350 drive");
        let uf2 = std::fs::read(&out).unwrap();
        assert_eq!(families(&uf2), [uf2::RP2350_ARM_S_FAMILY_ID; 3]);
    }

    #[test]
    fn pico_w_is_the_default_and_flashes_through_its_drive() {
        let dir = tempfile::tempdir().unwrap();
        let elf = firmware(dir.path());
        let drive = tempfile::tempdir().unwrap();
        let args = parse(&["--elf", elf.to_str().unwrap()]);
        run_with(args, |label| {
            assert_eq!(label, "RPI-RP2");
            vec![drive.path().to_owned()]
        })
        .unwrap();
        let uf2 = std::fs::read(drive.path().join("firmware.uf2")).unwrap();
        assert_eq!(families(&uf2), [uf2::RP2040_FAMILY_ID; 3]);
    }

    #[test]
    fn an_unknown_board_is_refused_by_name() {
        let error = Command::try_parse_from(["flash", "--board", "pico3"]).unwrap_err();
        let text = error.to_string();
        assert!(text.contains("pico3") && text.contains("pico2w"), "{text}");
    }
}
