//! The loadable contents of a 32-bit little-endian ARM ELF file: just enough of the ELF
//! program headers to place a firmware image in flash.
//!
//! Each `PT_LOAD` segment with file data is placed at its physical (load) address
//! `p_paddr`, which for initialised RAM data (`.data`) is its copy in flash, not its
//! run-time address. Segments without file data (`.bss`, stacks) hold nothing to flash.

use thiserror::Error;

const PT_LOAD: u32 = 1;
const EM_ARM: u16 = 40;
const HEADER_LEN: usize = 52;
const PROGRAM_HEADER_LEN: usize = 32;

/// Why a file could not be read as a firmware ELF.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum ElfError {
    #[error("not an ELF file")]
    NotElf,
    #[error("not a 32-bit little-endian ARM ELF (class {class}, data {data}, machine {machine})")]
    WrongKind { class: u8, data: u8, machine: u16 },
    #[error("truncated: {0} lies beyond the end of the file")]
    Truncated(&'static str),
    #[error("no loadable segment with data")]
    Empty,
}

/// Bytes to be placed at a physical address.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Segment {
    pub address: u32,
    pub data: Vec<u8>,
}

/// The segments of `elf` that carry data, in file order.
pub fn load_segments(elf: &[u8]) -> Result<Vec<Segment>, ElfError> {
    if elf.get(..4) != Some(b"\x7fELF".as_slice()) {
        return Err(ElfError::NotElf);
    }
    let header = elf.get(..HEADER_LEN).ok_or(ElfError::Truncated("header"))?;
    let (class, data, machine) = (header[4], header[5], u16_at(header, 18));
    if class != 1 || data != 1 || machine != EM_ARM {
        return Err(ElfError::WrongKind {
            class,
            data,
            machine,
        });
    }
    let table = usize_at(header, 28);
    let entry_len = usize::from(u16_at(header, 42));
    let count = usize::from(u16_at(header, 44));
    if entry_len < PROGRAM_HEADER_LEN {
        return Err(ElfError::Truncated("program header entry"));
    }
    let mut segments = Vec::new();
    for index in 0..count {
        let start = table + index * entry_len;
        let entry = elf
            .get(start..start + PROGRAM_HEADER_LEN)
            .ok_or(ElfError::Truncated("program header table"))?;
        let (kind, offset, address, size) = (
            u32_at(entry, 0),
            usize_at(entry, 4),
            u32_at(entry, 12),
            usize_at(entry, 16),
        );
        if kind != PT_LOAD || size == 0 {
            continue;
        }
        let data = elf
            .get(offset..offset + size)
            .ok_or(ElfError::Truncated("segment data"))?;
        segments.push(Segment {
            address,
            data: data.to_vec(),
        });
    }
    if segments.is_empty() {
        return Err(ElfError::Empty);
    }
    Ok(segments)
}

fn u16_at(bytes: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([bytes[at], bytes[at + 1]])
}

fn u32_at(bytes: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]])
}

fn usize_at(bytes: &[u8], at: usize) -> usize {
    // u32 always fits in usize on the hosts we build for.
    u32_at(bytes, at) as usize
}

/// Builds small ELF files for the tests of this module and of the UF2 writer.
#[cfg(test)]
pub mod build {
    /// One program header: (type, physical address, virtual address, file data, memory size).
    pub struct Program<'a> {
        pub kind: u32,
        pub paddr: u32,
        pub vaddr: u32,
        pub data: &'a [u8],
        pub mem_size: u32,
    }

    /// A 32-bit little-endian ARM ELF with `programs` as its program headers.
    pub fn elf(programs: &[Program<'_>]) -> Vec<u8> {
        let table = super::HEADER_LEN;
        let mut data_at = table + programs.len() * super::PROGRAM_HEADER_LEN;
        let mut out = vec![0u8; data_at];
        out[..4].copy_from_slice(b"\x7fELF");
        out[4] = 1;
        out[5] = 1;
        out[6] = 1;
        out[16..18].copy_from_slice(&2u16.to_le_bytes());
        out[18..20].copy_from_slice(&super::EM_ARM.to_le_bytes());
        out[28..32].copy_from_slice(&(table as u32).to_le_bytes());
        out[42..44].copy_from_slice(&(super::PROGRAM_HEADER_LEN as u16).to_le_bytes());
        out[44..46].copy_from_slice(&(programs.len() as u16).to_le_bytes());
        for (index, program) in programs.iter().enumerate() {
            let entry = table + index * super::PROGRAM_HEADER_LEN;
            let fields = [
                program.kind,
                data_at as u32,
                program.vaddr,
                program.paddr,
                program.data.len() as u32,
                program.mem_size,
            ];
            for (i, field) in fields.iter().enumerate() {
                out[entry + 4 * i..entry + 4 * i + 4].copy_from_slice(&field.to_le_bytes());
            }
            data_at += program.data.len();
        }
        for program in programs {
            out.extend_from_slice(program.data);
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::build::{Program, elf};
    use super::*;

    #[test]
    fn loads_at_physical_addresses_and_skips_empty_and_other_segments() {
        let text = [1u8; 300];
        let data = [2u8; 12];
        let file = elf(&[
            Program {
                kind: PT_LOAD,
                paddr: 0x1000_0000,
                vaddr: 0x1000_0000,
                data: &text,
                mem_size: 300,
            },
            // .data: runs in RAM, loaded from flash.
            Program {
                kind: PT_LOAD,
                paddr: 0x1000_0200,
                vaddr: 0x2000_0000,
                data: &data,
                mem_size: 12,
            },
            // .bss: no file data.
            Program {
                kind: PT_LOAD,
                paddr: 0x2000_0010,
                vaddr: 0x2000_0010,
                data: &[],
                mem_size: 4096,
            },
            // PT_NOTE-like: not loaded.
            Program {
                kind: 4,
                paddr: 0,
                vaddr: 0,
                data: &[9; 8],
                mem_size: 8,
            },
        ]);
        let segments = load_segments(&file).unwrap();
        assert_eq!(
            segments,
            vec![
                Segment {
                    address: 0x1000_0000,
                    data: text.to_vec()
                },
                Segment {
                    address: 0x1000_0200,
                    data: data.to_vec()
                },
            ]
        );
    }

    #[test]
    fn refuses_what_is_not_a_firmware_elf() {
        assert_eq!(load_segments(b"hello"), Err(ElfError::NotElf));
        let mut file = elf(&[Program {
            kind: PT_LOAD,
            paddr: 0x1000_0000,
            vaddr: 0x1000_0000,
            data: &[1; 4],
            mem_size: 4,
        }]);
        assert!(load_segments(&file[..40]).is_err());
        let truncated = &file[..file.len() - 2];
        assert_eq!(
            load_segments(truncated),
            Err(ElfError::Truncated("segment data"))
        );
        file[4] = 2;
        assert!(matches!(
            load_segments(&file),
            Err(ElfError::WrongKind { class: 2, .. })
        ));
        let empty = elf(&[]);
        assert_eq!(load_segments(&empty), Err(ElfError::Empty));
    }
}
