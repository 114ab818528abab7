//! The record journal: a ring of slots over several erase sectors, so the flash wears
//! evenly, and a write never touches the sector holding the newest good record.
//!
//! Each write goes to the slot after the newest record's, with the next sequence number;
//! loading picks the valid slot with the newest sequence. A write entering a sector erases
//! that sector first (its slots hold the oldest records of the ring); a write to a slot
//! of the newest record's own sector goes only into a blank slot, so a power loss in the
//! middle of a write (a torn slot) leaves the newest record intact. When the next slot is
//! not blank (a torn or failed write left something there), the write skips to the start
//! of the next sector. Every write is read back; one that reads back differently fails,
//! and the newest record stays where it was. A record identical to the last one written
//! is not written again, to spare the flash.
//!
//! Wear: each sector is erased once per round of the ring, that is once per
//! `S::SLOTS` writes (docs/reliability.md has the board's lifetime in moves).

use crate::record::{self, InvalidSlot, RECORD_LEN, Record};
use crate::storage::{Storage, StorageError};

/// Something was written, but no slot checks out.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Corrupt;

/// Which slot holds the newest record.
pub struct Journal {
    newest: Option<(u8, u32)>,
    last_payload: Option<u32>,
}

impl Journal {
    /// The newest valid record; `Ok(None)` when every slot is blank (a board that never
    /// saved anything).
    pub fn load<S: Storage>(storage: &mut S) -> (Self, Result<Option<Record>, Corrupt>) {
        const {
            assert!(S::SLOT_SIZE >= RECORD_LEN, "storage slots are too small");
            assert!(
                S::SLOTS_PER_SECTOR > 0 && S::SLOTS.is_multiple_of(S::SLOTS_PER_SECTOR),
                "slots come in whole sectors"
            );
            assert!(
                S::SLOTS / S::SLOTS_PER_SECTOR >= 3,
                "the ring needs three sectors"
            );
        };
        let mut newest: Option<(u8, u32, Record)> = None;
        let mut blank = true;
        let mut buf = [0u8; RECORD_LEN];
        for slot in 0..S::SLOTS {
            let decoded = match storage.read(slot, &mut buf) {
                Ok(()) => record::decode(&buf),
                Err(_) => Err(InvalidSlot),
            };
            match decoded {
                Ok(None) => {}
                Err(InvalidSlot) => blank = false,
                Ok(Some((sequence, record))) => {
                    blank = false;
                    if newest
                        .as_ref()
                        .is_none_or(|&(_, best, _)| is_newer(sequence, best))
                    {
                        newest = Some((slot, sequence, record));
                    }
                }
            }
        }
        let journal = Self {
            newest: newest.as_ref().map(|&(slot, sequence, _)| (slot, sequence)),
            last_payload: None,
        };
        let loaded = match newest {
            Some((_, _, record)) => Ok(Some(record)),
            None if blank => Ok(None),
            None => Err(Corrupt),
        };
        (journal, loaded)
    }

    /// Writes `record` to the slot after the newest record's.
    pub fn save<S: Storage>(
        &mut self,
        storage: &mut S,
        record: &Record,
    ) -> Result<(), StorageError> {
        let sequence = self
            .newest
            .map_or(0, |(_, sequence)| sequence.wrapping_add(1));
        let mut buf = [0u8; RECORD_LEN];
        let payload = record::encode(record, sequence, &mut buf).ok_or(StorageError::Encoding)?;
        if self.last_payload == Some(payload) {
            return Ok(());
        }
        let (slot, erase) = self.next_slot(storage)?;
        if erase {
            storage.erase(slot)?;
        }
        storage.write(slot, &buf)?;
        let mut check = [0u8; RECORD_LEN];
        storage.read(slot, &mut check)?;
        if check != buf {
            // Not the newest: the last good record stays where it was.
            return Err(StorageError::ReadBack);
        }
        self.newest = Some((slot, sequence));
        self.last_payload = Some(payload);
        Ok(())
    }

    /// The slot the next record goes to, and whether its sector must be erased first.
    fn next_slot<S: Storage>(&self, storage: &mut S) -> Result<(u8, bool), StorageError> {
        let per_sector = S::SLOTS_PER_SECTOR;
        let Some((newest, _)) = self.newest else {
            return Ok((0, true));
        };
        let next = (newest + 1) % S::SLOTS;
        if next.is_multiple_of(per_sector) {
            return Ok((next, true));
        }
        let mut bytes = [0u8; RECORD_LEN];
        storage.read(next, &mut bytes)?;
        if bytes.iter().all(|&b| b == 0xFF) {
            Ok((next, false))
        } else {
            // Something was left in the newest record's sector: start the next sector.
            Ok(((next - next % per_sector + per_sector) % S::SLOTS, true))
        }
    }
}

/// Sequence comparison that survives wrap-around.
fn is_newer(sequence: u32, than: u32) -> bool {
    (sequence.wrapping_sub(than) as i32) > 0
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::storage::RamStorage;

    fn record(key: u8) -> Record {
        Record {
            key: Some([key; 32]),
            ..Record::default()
        }
    }

    /// The slot holding the record with `key`.
    fn slot_of(storage: &RamStorage, key: u8) -> Option<usize> {
        (0..usize::from(RamStorage::SLOTS)).find(|&slot| {
            let bytes = &storage.as_bytes()[slot * RECORD_LEN..][..RECORD_LEN];
            record::decode(bytes)
                .is_ok_and(|found| found.is_some_and(|(_, found)| found.key == Some([key; 32])))
        })
    }

    #[test]
    fn the_newest_wins_and_writes_go_round_the_ring() {
        let mut storage = RamStorage::new();
        let (mut journal, loaded) = Journal::load(&mut storage);
        assert_eq!(loaded, Ok(None));
        let slots = RamStorage::SLOTS;
        for key in 1..=2 * slots + 1 {
            journal.save(&mut storage, &record(key)).unwrap();
            assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(key))));
            // One slot after the other, round and round.
            assert_eq!(slot_of(&storage, key), Some(usize::from((key - 1) % slots)));
        }
        let writes = u32::from(2 * slots + 1);
        assert_eq!(storage.writes(), writes);
        // Each sector erased once per round (the first round erases them all as well).
        let sectors = u32::from(slots / RamStorage::SLOTS_PER_SECTOR);
        assert_eq!(storage.erases(), 2 * sectors + 1);
        // Unchanged: not written again.
        journal.save(&mut storage, &record(2 * slots + 1)).unwrap();
        assert_eq!(storage.writes(), writes);
    }

    #[test]
    fn torn_write_keeps_the_previous_record() {
        // The record is 51 bytes long: tear it anywhere before its last byte.
        for keep in [0, 1, 11, 12, 30, 50] {
            let mut storage = RamStorage::new();
            let (mut journal, _) = Journal::load(&mut storage);
            journal.save(&mut storage, &record(1)).unwrap();
            journal.save(&mut storage, &record(2)).unwrap();
            storage.tear_next_write(keep);
            assert_eq!(
                journal.save(&mut storage, &record(3)),
                Err(StorageError::ReadBack),
                "a torn write does not read back"
            );
            let mut storage = storage.power_cycled();
            let (mut journal, loaded) = Journal::load(&mut storage);
            assert_eq!(loaded, Ok(Some(record(2))), "torn after {keep} bytes");
            // The next write lands elsewhere, and the good record stays until it did.
            let good = slot_of(&storage, 2);
            journal.save(&mut storage, &record(4)).unwrap();
            assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(4))));
            assert_eq!(slot_of(&storage, 2), good, "record 2 untouched");
        }
    }

    #[test]
    fn corrupted_newest_falls_back_and_both_corrupt_is_reported() {
        let mut storage = RamStorage::new();
        let (mut journal, _) = Journal::load(&mut storage);
        journal.save(&mut storage, &record(1)).unwrap();
        journal.save(&mut storage, &record(2)).unwrap();
        // Record 2 went to slot 1.
        storage.as_bytes_mut()[RECORD_LEN + 20] ^= 1;
        assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(1))));
        storage.as_bytes_mut()[20] ^= 1;
        assert_eq!(Journal::load(&mut storage).1, Err(Corrupt));
    }

    #[test]
    fn a_write_that_reads_back_wrong_fails_and_keeps_the_last_record() {
        let mut storage = RamStorage::new();
        let (mut journal, _) = Journal::load(&mut storage);
        journal.save(&mut storage, &record(1)).unwrap();
        storage.set_corrupting(true);
        assert_eq!(
            journal.save(&mut storage, &record(2)),
            Err(StorageError::ReadBack)
        );
        assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(1))));
        // Not taken for written: the same record is written again once the device works.
        storage.set_corrupting(false);
        journal.save(&mut storage, &record(2)).unwrap();
        assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(2))));
    }

    #[test]
    fn sequence_wraps() {
        assert!(is_newer(0, u32::MAX));
        assert!(is_newer(5, 4));
        assert!(!is_newer(4, 5));
    }

    #[test]
    fn failing_storage_reports_and_keeps_the_last_record() {
        let mut storage = RamStorage::new();
        let (mut journal, _) = Journal::load(&mut storage);
        journal.save(&mut storage, &record(1)).unwrap();
        storage.set_failing(true);
        assert_eq!(
            journal.save(&mut storage, &record(2)),
            Err(StorageError::Device)
        );
        storage.set_failing(false);
        assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(1))));
        journal.save(&mut storage, &record(2)).unwrap();
        assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(2))));
    }
}
