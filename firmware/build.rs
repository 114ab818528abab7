//! Build script: only does something for the images on a Raspberry Pi chip (features
//! `rp2040`, `rp235x`) on a bare-metal ARM target; host builds of the core skip it.
//!
//! 1. Puts the chip's memory map (`memory-rp2040.x` or `memory-rp235x.x`) on the linker
//!    search path as `memory.x` and passes the linker scripts to the binaries: `link.x`
//!    (cortex-m-rt), on the RP2040 `link-rp.x` (embassy-rp: places the boot2 loader at the
//!    start of flash; the RP2350's map places the image definition block itself) and, for
//!    the board images, `defmt.x`.
//! 2. For the board images, finds the CYW43439 board nvram (radio configuration), which is
//!    not kept in this repository: `OPTALIGN_CYW43_NVRAM` names it (absolute, or relative
//!    to the workspace root); unset, `../shared/cyw43/nvram_rp2040.bin` beside the
//!    workspace is used. Its path goes to the crate as `OPTALIGN_CYW43_NVRAM_PATH`.

use std::env;
use std::fs;
use std::path::{Path, PathBuf};

const NVRAM_ENV: &str = "OPTALIGN_CYW43_NVRAM";
/// The fallback, relative to the workspace root.
const NVRAM_FALLBACK: &str = "../shared/cyw43/nvram_rp2040.bin";
/// The Pico W nvram is ~750 bytes of NUL-separated `key=value` text.
const NVRAM_MAX_LEN: usize = 4096;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed={NVRAM_ENV}");
    let board = env::var_os("CARGO_FEATURE_BOARD").is_some();
    let target = env::var("TARGET").unwrap_or_default();
    let chip = match (
        env::var_os("CARGO_FEATURE_RP2040").is_some(),
        env::var_os("CARGO_FEATURE_RP235X").is_some(),
    ) {
        (false, false) => return,
        (true, false) => Chip::Rp2040,
        (false, true) => Chip::Rp235x,
        (true, true) => {
            return println!("cargo::error=features rp2040 and rp235x exclude each other");
        }
    };
    if !target.starts_with("thumbv") {
        return;
    }
    if !target.starts_with(chip.target()) {
        return println!(
            "cargo::error=the {} images build for {}*, not {target}",
            chip.name(),
            chip.target()
        );
    }
    let memory = chip.memory_map();
    println!("cargo:rerun-if-changed={memory}");
    let Some(manifest) = env::var_os("CARGO_MANIFEST_DIR").map(PathBuf::from) else {
        return println!("cargo::error=CARGO_MANIFEST_DIR is not set");
    };
    let Some(out) = env::var_os("OUT_DIR").map(PathBuf::from) else {
        return println!("cargo::error=OUT_DIR is not set");
    };
    if let Err(error) = fs::copy(manifest.join(memory), out.join("memory.x")) {
        return println!(
            "cargo::error=cannot copy {memory} to {}: {error}",
            out.display()
        );
    }
    println!("cargo:rustc-link-search={}", out.display());
    for script in ["--nmagic", "-Tlink.x"] {
        println!("cargo:rustc-link-arg-bins={script}");
    }
    if chip == Chip::Rp2040 {
        println!("cargo:rustc-link-arg-bins=-Tlink-rp.x");
    }
    if board {
        println!("cargo:rustc-link-arg-bins=-Tdefmt.x");
        let workspace = manifest.join("..");
        match find_nvram(&workspace) {
            Ok(path) => {
                println!("cargo:rerun-if-changed={}", path.display());
                println!(
                    "cargo:rustc-env=OPTALIGN_CYW43_NVRAM_PATH={}",
                    path.display()
                );
            }
            // `cargo::error` lines fail the build with just these messages.
            Err(message) => message
                .lines()
                .for_each(|line| println!("cargo::error={line}")),
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Chip {
    Rp2040,
    Rp235x,
}

impl Chip {
    fn name(self) -> &'static str {
        match self {
            Self::Rp2040 => "RP2040",
            Self::Rp235x => "RP2350",
        }
    }

    /// The target triple's prefix: Cortex-M0+ or Cortex-M33 with its FPU.
    fn target(self) -> &'static str {
        match self {
            Self::Rp2040 => "thumbv6m-none-eabi",
            Self::Rp235x => "thumbv8m.main-none-eabihf",
        }
    }

    fn memory_map(self) -> &'static str {
        match self {
            Self::Rp2040 => "memory-rp2040.x",
            Self::Rp235x => "memory-rp235x.x",
        }
    }
}

fn find_nvram(workspace: &Path) -> Result<PathBuf, String> {
    const HOW: &str = "The Pico W radio configuration nvram_rp2040.bin is not part of this \
        repository.\nGet it from the embassy project (cyw43-firmware/nvram_rp2040.bin, Infineon \
        Permissive Binary License), then set OPTALIGN_CYW43_NVRAM=/path/to/nvram_rp2040.bin \
        or put it at ../shared/cyw43/nvram_rp2040.bin beside the workspace.";
    let (setting, path) = match env::var_os(NVRAM_ENV) {
        Some(value) => (
            format!("{NVRAM_ENV}={}", PathBuf::from(&value).display()),
            workspace.join(value),
        ),
        None => (
            format!("{NVRAM_ENV} is unset, and the fallback"),
            workspace.join(NVRAM_FALLBACK),
        ),
    };
    check_nvram(&path)
        .map_err(|why| format!("CYW43 nvram: {setting} ({}): {why}\n{HOW}", path.display()))
}

fn check_nvram(path: &Path) -> Result<PathBuf, String> {
    let path = path.canonicalize().map_err(|e| e.to_string())?;
    let bytes = fs::read(&path).map_err(|e| e.to_string())?;
    if bytes.is_empty() || bytes.len() > NVRAM_MAX_LEN {
        return Err(format!(
            "{} bytes, expected 1..={NVRAM_MAX_LEN}",
            bytes.len()
        ));
    }
    let text = bytes
        .iter()
        .all(|&b| b == 0 || b == b' ' || b.is_ascii_graphic());
    let first = bytes.split(|&b| b == 0).find(|r| !r.is_empty());
    if !text || !first.is_some_and(|record| record.contains(&b'=')) {
        return Err("does not look like CYW43 nvram (NUL-separated key=value text)".into());
    }
    Ok(path)
}
