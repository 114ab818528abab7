//! The persisted record (configuration, positions, credentials) and its slot encoding.
//!
//! Slot layout, little endian: magic `"OPTA"`, format version (u16), sequence number
//! (u32), payload length (u16), the postcard payload, then the CRC-32C of everything
//! before it. A slot that is all 0xFF (erased) or all 0x00 is blank; anything else that
//! does not check out is invalid. Bump [`RECORD_VERSION`] whenever [`Record`] (or a
//! protocol type inside it, such as `AxisConfig`) changes its encoding, and keep reading
//! the versions before it (version 1 had no boot counter).

use crc::{CRC_32_ISCSI, Crc};
use heapless::{String, Vec};
use optalign_protocol::limits::{KEY_LEN, PASSPHRASE_LEN, SSID_LEN};
use optalign_protocol::{AxisConfig, MAX_AXES, Slack};
use serde::{Deserialize, Serialize};

/// Bytes of one encoded record slot (a storage slot must be at least this large).
pub const RECORD_LEN: usize = 1024;

/// Version of the record layout.
pub const RECORD_VERSION: u16 = 2;

const MAGIC: [u8; 4] = *b"OPTA";
const HEADER_LEN: usize = 12;
const CRC_LEN: usize = 4;
const CRC32C: Crc<u32> = Crc::<u32>::new(&CRC_32_ISCSI);

/// Wi-Fi network credentials.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct WifiCredentials {
    pub ssid: String<SSID_LEN>,
    pub passphrase: String<PASSPHRASE_LEN>,
}

/// One axis's saved configuration and state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AxisRecord {
    pub config: AxisConfig,
    /// Logical position.
    pub position: i32,
    /// Motor step counter (logical sense).
    pub motor_steps: i32,
    /// Step counter the coils see (physical sense), so power-up energises the rotor's phase.
    pub coil_steps: i32,
    pub slack: Slack,
    /// Steps above the negative contact of the dead band (see [`crate::gear`]).
    pub band: u16,
}

/// Everything the controller keeps across power cycles.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Record {
    pub key: Option<[u8; KEY_LEN]>,
    pub wifi: Option<WifiCredentials>,
    pub axes: Vec<AxisRecord, MAX_AXES>,
    /// The number of the latest boot that issued a challenge nonce (see
    /// [`crate::nonce`]).
    pub boots: u32,
}

/// A record as version 1 wrote it: no boot counter.
#[derive(Deserialize)]
struct RecordV1 {
    key: Option<[u8; KEY_LEN]>,
    wifi: Option<WifiCredentials>,
    axes: Vec<AxisRecord, MAX_AXES>,
}

impl From<RecordV1> for Record {
    fn from(old: RecordV1) -> Self {
        Self {
            key: old.key,
            wifi: old.wifi,
            axes: old.axes,
            boots: 0,
        }
    }
}

/// A slot that is neither blank nor a valid record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct InvalidSlot;

/// Encodes `record` into `slot`; returns the CRC-32C of the payload alone (to tell
/// whether anything changed since the last write).
pub fn encode(record: &Record, sequence: u32, slot: &mut [u8; RECORD_LEN]) -> Option<u32> {
    let (header, rest) = slot.split_at_mut(HEADER_LEN);
    let body = rest.get_mut(..RECORD_LEN - HEADER_LEN - CRC_LEN)?;
    let len = postcard::to_slice(record, body).ok()?.len();
    let payload_crc = CRC32C.checksum(body.get(..len)?);
    header[..4].copy_from_slice(&MAGIC);
    header[4..6].copy_from_slice(&RECORD_VERSION.to_le_bytes());
    header[6..10].copy_from_slice(&sequence.to_le_bytes());
    header[10..12].copy_from_slice(&u16::try_from(len).ok()?.to_le_bytes());
    let end = HEADER_LEN + len;
    let crc = CRC32C.checksum(slot.get(..end)?);
    slot.get_mut(end..end + CRC_LEN)?
        .copy_from_slice(&crc.to_le_bytes());
    Some(payload_crc)
}

/// Reads a slot: `Ok(None)` when blank, else its sequence number and record.
pub fn decode(slot: &[u8]) -> Result<Option<(u32, Record)>, InvalidSlot> {
    if slot.iter().all(|&b| b == 0xFF) || slot.iter().all(|&b| b == 0) {
        return Ok(None);
    }
    decode_valid(slot).map(Some).ok_or(InvalidSlot)
}

fn decode_valid(slot: &[u8]) -> Option<(u32, Record)> {
    let field = |range: core::ops::Range<usize>| slot.get(range);
    if field(0..4)? != MAGIC {
        return None;
    }
    let version = u16::from_le_bytes(field(4..6)?.try_into().ok()?);
    let sequence = u32::from_le_bytes(field(6..10)?.try_into().ok()?);
    let len = usize::from(u16::from_le_bytes(field(10..12)?.try_into().ok()?));
    let end = HEADER_LEN + len;
    let stored = u32::from_le_bytes(field(end..end + CRC_LEN)?.try_into().ok()?);
    if CRC32C.checksum(field(0..end)?) != stored {
        return None;
    }
    let payload = field(HEADER_LEN..end)?;
    let record = match version {
        1 => postcard::from_bytes::<RecordV1>(payload).ok()?.into(),
        RECORD_VERSION => postcard::from_bytes(payload).ok()?,
        _ => return None,
    };
    Some((sequence, record))
}

#[cfg(test)]
mod tests {
    use optalign_protocol::Capabilities;

    use super::*;
    use crate::config::default_config;

    fn full_record() -> Record {
        let axis = AxisRecord {
            config: default_config(Capabilities(Capabilities::UNIPOLAR_HALF_STEP)),
            position: i32::MIN,
            motor_steps: i32::MAX,
            coil_steps: -1,
            slack: Slack::TakenUpNegative,
            band: u16::MAX,
        };
        Record {
            key: Some([0xAB; KEY_LEN]),
            wifi: Some(WifiCredentials {
                ssid: String::try_from("s".repeat(SSID_LEN).as_str()).unwrap(),
                passphrase: String::try_from("p".repeat(PASSPHRASE_LEN).as_str()).unwrap(),
            }),
            axes: [axis; MAX_AXES].into_iter().collect(),
            boots: u32::MAX,
        }
    }

    #[test]
    fn largest_record_round_trips() {
        let record = full_record();
        let mut slot = [0; RECORD_LEN];
        assert!(encode(&record, 7, &mut slot).is_some());
        assert_eq!(decode(&slot), Ok(Some((7, record))));
    }

    #[test]
    fn any_flipped_byte_is_detected() {
        let mut slot = [0; RECORD_LEN];
        encode(&full_record(), 1, &mut slot).unwrap();
        let used = HEADER_LEN + usize::from(u16::from_le_bytes([slot[10], slot[11]])) + CRC_LEN;
        for i in 0..used {
            let mut bad = slot;
            bad[i] ^= 0x10;
            assert_eq!(decode(&bad), Err(InvalidSlot), "byte {i}");
        }
    }

    #[test]
    fn a_version_1_record_is_read_with_no_boots_counted() {
        #[derive(Serialize)]
        struct V1<'a> {
            key: &'a Option<[u8; KEY_LEN]>,
            wifi: &'a Option<WifiCredentials>,
            axes: &'a Vec<AxisRecord, MAX_AXES>,
        }
        let record = full_record();
        let mut slot = [0; RECORD_LEN];
        encode(&record, 3, &mut slot).unwrap();
        // Rewrite the slot as version 1 did: the payload without the boot counter.
        let old = V1 {
            key: &record.key,
            wifi: &record.wifi,
            axes: &record.axes,
        };
        let len = postcard::to_slice(&old, &mut slot[HEADER_LEN..])
            .unwrap()
            .len();
        slot[4..6].copy_from_slice(&1u16.to_le_bytes());
        slot[10..12].copy_from_slice(&u16::try_from(len).unwrap().to_le_bytes());
        let end = HEADER_LEN + len;
        let crc = CRC32C.checksum(&slot[..end]);
        slot[end..end + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
        let expected = Record { boots: 0, ..record };
        assert_eq!(decode(&slot), Ok(Some((3, expected))));
        // Another unknown version is invalid.
        slot[4..6].copy_from_slice(&9u16.to_le_bytes());
        let crc = CRC32C.checksum(&slot[..end]);
        slot[end..end + CRC_LEN].copy_from_slice(&crc.to_le_bytes());
        assert_eq!(decode(&slot), Err(InvalidSlot));
    }

    #[test]
    fn blank_slots() {
        assert_eq!(decode(&[0xFF; RECORD_LEN]), Ok(None));
        assert_eq!(decode(&[0; RECORD_LEN]), Ok(None));
        assert_eq!(decode(&[1; RECORD_LEN]), Err(InvalidSlot));
    }
}
