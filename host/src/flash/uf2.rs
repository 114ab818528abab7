//! UF2 images for the boot loaders of the RP2040 (the RPI-RP2 USB drive) and the RP2350
//! (the RP2350 drive).
//!
//! A UF2 file is a sequence of 512-byte blocks, each carrying 256 bytes to be written at
//! a 256-byte aligned flash address, tagged with the chip's family id so the boot ROM
//! accepts it. Bytes of a 256-byte page that no segment covers are written as 0.
//! Format: <https://github.com/microsoft/uf2>; RP2040 specifics: RP2040 datasheet 2.8.4;
//! RP2350: datasheet 5.5 (family ids as in pico-sdk's `boot/uf2.h` and picotool). Both
//! chips map their flash for execution at 0x10000000.

use std::collections::BTreeMap;

use thiserror::Error;

use super::elf::Segment;

pub const BLOCK_LEN: usize = 512;
pub const PAYLOAD_LEN: usize = 256;
pub const MAGIC_START_0: u32 = 0x0A32_4655;
pub const MAGIC_START_1: u32 = 0x9E5D_5157;
pub const MAGIC_END: u32 = 0x0AB1_6F30;
/// Flags: the family id field is present.
pub const FLAG_FAMILY_ID: u32 = 0x0000_2000;
pub const RP2040_FAMILY_ID: u32 = 0xE48B_FF56;
/// An image for the RP2350's Arm cores in secure mode (what embassy-rp builds).
pub const RP2350_ARM_S_FAMILY_ID: u32 = 0xE48B_FF59;

/// The flash as seen by either boot loader: execute-in-place, up to 16 MiB.
pub const FLASH_START: u32 = 0x1000_0000;
pub const FLASH_END: u32 = 0x1100_0000;

/// Why segments cannot go into a UF2 for the flash.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum Uf2Error {
    #[error(
        "segment at {address:#010x}..{end:#010x} is outside the flash \
         ({FLASH_START:#010x}..{FLASH_END:#010x}): is this a flash image for the board?"
    )]
    OutsideFlash { address: u32, end: u64 },
}

/// Encodes `segments` as UF2 blocks tagged `family_id`, in address order.
pub fn encode(segments: &[Segment], family_id: u32) -> Result<Vec<u8>, Uf2Error> {
    let mut pages: BTreeMap<u32, [u8; PAYLOAD_LEN]> = BTreeMap::new();
    for segment in segments {
        let end = u64::from(segment.address) + segment.data.len() as u64;
        if segment.address < FLASH_START || end > u64::from(FLASH_END) {
            return Err(Uf2Error::OutsideFlash {
                address: segment.address,
                end,
            });
        }
        for (address, &byte) in (segment.address..).zip(&segment.data) {
            let page = address & !(PAYLOAD_LEN as u32 - 1);
            pages.entry(page).or_insert([0; PAYLOAD_LEN])[(address - page) as usize] = byte;
        }
    }
    let count = u32::try_from(pages.len()).unwrap_or(u32::MAX);
    let mut out = Vec::with_capacity(pages.len() * BLOCK_LEN);
    for (number, (address, payload)) in (0u32..).zip(&pages) {
        let mut block = [0u8; BLOCK_LEN];
        let words = [
            MAGIC_START_0,
            MAGIC_START_1,
            FLAG_FAMILY_ID,
            *address,
            PAYLOAD_LEN as u32,
            number,
            count,
            family_id,
        ];
        for (i, word) in words.iter().enumerate() {
            block[4 * i..4 * i + 4].copy_from_slice(&word.to_le_bytes());
        }
        block[32..32 + PAYLOAD_LEN].copy_from_slice(payload);
        block[BLOCK_LEN - 4..].copy_from_slice(&MAGIC_END.to_le_bytes());
        out.extend_from_slice(&block);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::flash::elf::build::{Program, elf};
    use crate::flash::elf::load_segments;

    fn word(block: &[u8], at: usize) -> u32 {
        u32::from_le_bytes(block[at..at + 4].try_into().unwrap())
    }

    /// Reads UF2 blocks back into (address, payload) pairs, checking every fixed field
    /// (the family id: RP2040's).
    fn decode(uf2: &[u8]) -> Vec<(u32, Vec<u8>)> {
        assert_eq!(uf2.len() % BLOCK_LEN, 0);
        let count = uf2.len() / BLOCK_LEN;
        uf2.chunks(BLOCK_LEN)
            .enumerate()
            .map(|(number, block)| {
                assert_eq!(word(block, 0), MAGIC_START_0);
                assert_eq!(word(block, 4), MAGIC_START_1);
                assert_eq!(word(block, 8), FLAG_FAMILY_ID);
                assert_eq!(word(block, 16), PAYLOAD_LEN as u32);
                assert_eq!(word(block, 20), number as u32);
                assert_eq!(word(block, 24), count as u32);
                assert_eq!(word(block, 28), RP2040_FAMILY_ID);
                assert_eq!(word(block, BLOCK_LEN - 4), MAGIC_END);
                assert!(
                    block[32 + PAYLOAD_LEN..BLOCK_LEN - 4]
                        .iter()
                        .all(|&b| b == 0)
                );
                let address = word(block, 12);
                assert_eq!(address % PAYLOAD_LEN as u32, 0, "page aligned");
                (address, block[32..32 + PAYLOAD_LEN].to_vec())
            })
            .collect()
    }

    fn segment(address: u32, data: Vec<u8>) -> Segment {
        Segment { address, data }
    }

    #[test]
    fn blocks_cover_each_page_once_in_address_order() {
        // boot2 (one full page), code spilling into a third page, and .data sharing a page
        // with the end of the code.
        let code: Vec<u8> = (0..300u32).map(|i| (i % 251) as u8 + 1).collect();
        let segments = [
            segment(0x1000_0100, code.clone()),
            segment(0x1000_0000, vec![0xB2; 256]),
            segment(0x1000_0100 + 300, vec![0xDA; 8]),
        ];
        let uf2 = encode(&segments, RP2040_FAMILY_ID).unwrap();
        let blocks = decode(&uf2);
        let addresses: Vec<u32> = blocks.iter().map(|b| b.0).collect();
        assert_eq!(addresses, [0x1000_0000, 0x1000_0100, 0x1000_0200]);
        assert!(blocks[0].1.iter().all(|&b| b == 0xB2));
        assert_eq!(blocks[1].1, code[..256]);
        assert_eq!(blocks[2].1[..44], code[256..]);
        assert_eq!(blocks[2].1[44..52], [0xDA; 8]);
        assert!(blocks[2].1[52..].iter().all(|&b| b == 0), "padding is zero");
    }

    #[test]
    fn an_elf_round_trips_through_uf2() {
        let text: Vec<u8> = (0..1000u32).map(|i| (i * 7 % 256) as u8).collect();
        let data = vec![0x5A; 20];
        let file = elf(&[
            Program {
                kind: 1,
                paddr: 0x1000_0000,
                vaddr: 0x1000_0000,
                data: &text,
                mem_size: 1000,
            },
            Program {
                kind: 1,
                paddr: 0x1000_03E8,
                vaddr: 0x2000_0000,
                data: &data,
                mem_size: 20,
            },
            Program {
                kind: 1,
                paddr: 0x2000_0014,
                vaddr: 0x2000_0014,
                data: &[],
                mem_size: 512,
            },
        ]);
        let uf2 = encode(&load_segments(&file).unwrap(), RP2040_FAMILY_ID).unwrap();
        let blocks = decode(&uf2);
        assert_eq!(blocks.len(), 1020usize.div_ceil(PAYLOAD_LEN));
        let mut flash = vec![0u8; blocks.len() * PAYLOAD_LEN];
        for (address, payload) in blocks {
            let at = (address - FLASH_START) as usize;
            flash[at..at + PAYLOAD_LEN].copy_from_slice(&payload);
        }
        assert_eq!(flash[..1000], text[..]);
        assert_eq!(flash[1000..1020], data[..]);
    }

    #[test]
    fn every_block_carries_the_family_id_asked_for() {
        let segments = [segment(0x1000_0000, vec![7; 600])];
        let uf2 = encode(&segments, RP2350_ARM_S_FAMILY_ID).unwrap();
        assert_eq!(uf2.len(), 3 * BLOCK_LEN);
        for block in uf2.chunks(BLOCK_LEN) {
            assert_eq!(word(block, 8), FLAG_FAMILY_ID);
            assert_eq!(word(block, 28), RP2350_ARM_S_FAMILY_ID);
        }
    }

    #[test]
    fn segments_outside_flash_are_refused() {
        let error = encode(&[segment(0x2000_0000, vec![1; 4])], RP2040_FAMILY_ID).unwrap_err();
        assert!(error.to_string().contains("0x20000000"), "{error}");
        let error = encode(&[segment(FLASH_END - 2, vec![1; 4])], RP2040_FAMILY_ID).unwrap_err();
        assert!(matches!(error, Uf2Error::OutsideFlash { .. }));
    }
}
