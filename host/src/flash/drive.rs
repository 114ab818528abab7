//! Finding a boot loader's USB drive among the mounted file systems.
//!
//! A board held in BOOTSEL mode shows up as a small FAT drive whose `INFO_UF2.TXT` names
//! the boot loader (`Board-ID: RPI-RP2` on an RP2040, `Board-ID: RP2350` on an RP2350).
//! Copying a UF2 file onto it flashes the board, which then reboots into the new image.

use std::path::{Path, PathBuf};

/// The file every UF2 boot loader drive holds.
pub const INFO_FILE: &str = "INFO_UF2.TXT";

/// Mounted boot loader drives whose info file says `Board-ID: {board_id}`, in the order
/// found.
pub fn find_boot_drives(board_id: &str) -> Vec<PathBuf> {
    candidates()
        .into_iter()
        .filter(|dir| is_boot_drive(dir, board_id))
        .collect()
}

/// Whether `dir` is the root of a boot loader drive whose info file says
/// `Board-ID: {board_id}`.
pub fn is_boot_drive(dir: &Path, board_id: &str) -> bool {
    std::fs::read_to_string(dir.join(INFO_FILE)).is_ok_and(|info| {
        info.lines().any(|line| {
            line.trim()
                .strip_prefix("Board-ID:")
                .is_some_and(|id| id.trim() == board_id)
        })
    })
}

/// Mount points worth looking at: everything in the mount table (Linux), plus the usual
/// places desktops mount removable drives.
fn candidates() -> Vec<PathBuf> {
    let mut dirs: Vec<PathBuf> = std::fs::read_to_string("/proc/mounts")
        .map(|table| mount_points(&table))
        .unwrap_or_default();
    let user = std::env::var("USER").unwrap_or_default();
    for parent in [
        PathBuf::from("/Volumes"),
        Path::new("/media").join(&user),
        Path::new("/run/media").join(&user),
    ] {
        if let Ok(entries) = std::fs::read_dir(parent) {
            dirs.extend(entries.flatten().map(|entry| entry.path()));
        }
    }
    dirs.dedup();
    dirs
}

/// The mount points of a `/proc/mounts` table (second field, octal escapes decoded).
fn mount_points(table: &str) -> Vec<PathBuf> {
    table
        .lines()
        .filter_map(|line| line.split_whitespace().nth(1))
        .map(|field| PathBuf::from(unescape(field)))
        .collect()
}

/// Decodes the `\040`-style octal escapes the kernel uses for spaces and the like.
fn unescape(field: &str) -> String {
    let bytes = field.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let escaped = bytes
            .get(i + 1..i + 4)
            .filter(|digits| bytes[i] == b'\\' && digits.iter().all(|d| (b'0'..=b'7').contains(d)))
            .and_then(|digits| u8::from_str_radix(std::str::from_utf8(digits).ok()?, 8).ok());
        match escaped {
            Some(byte) => {
                out.push(byte);
                i += 4;
            }
            None => {
                out.push(bytes[i]);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn mount_points_are_read_and_unescaped() {
        let table = "proc /proc proc rw 0 0\n\
                     /dev/sdb1 /media/lab/RPI-RP2 vfat rw 0 0\n\
                     /dev/sdc1 /mnt/with\\040space vfat rw 0 0\n";
        assert_eq!(
            mount_points(table),
            [
                PathBuf::from("/proc"),
                PathBuf::from("/media/lab/RPI-RP2"),
                PathBuf::from("/mnt/with space"),
            ]
        );
        assert_eq!(unescape("a\\134b\\0"), "a\\b\\0");
    }

    #[test]
    fn only_the_chips_own_boot_drive_matches() {
        let dir = tempfile::tempdir().unwrap();
        assert!(!is_boot_drive(dir.path(), "RPI-RP2"));
        std::fs::write(
            dir.path().join(INFO_FILE),
            "UF2 Bootloader v3.0\nModel: Raspberry Pi RP2\nBoard-ID: RPI-RP2\n",
        )
        .unwrap();
        assert!(is_boot_drive(dir.path(), "RPI-RP2"));
        assert!(!is_boot_drive(dir.path(), "RP2350"));
        std::fs::write(
            dir.path().join(INFO_FILE),
            "UF2 Bootloader v1.0\nModel: Raspberry Pi RP2350\nBoard-ID: RP2350\n",
        )
        .unwrap();
        assert!(!is_boot_drive(dir.path(), "RPI-RP2"));
        assert!(is_boot_drive(dir.path(), "RP2350"));
    }
}
