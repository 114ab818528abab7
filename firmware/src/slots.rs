//! The two-slot journal: a write never touches the slot holding the newest good record.
//!
//! Each write goes to the other slot with the next sequence number, so a power loss in the
//! middle of a write (a torn slot) leaves the previous record intact, and loading picks the
//! valid slot with the newest sequence. Every write is read back; one that reads back
//! differently fails, and the next write goes to the same slot. A record identical to the last one written is not
//! written again, to spare the flash.

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
    /// The newest valid record; `Ok(None)` when both slots are blank (a board that never
    /// saved anything).
    pub fn load<S: Storage>(storage: &mut S) -> (Self, Result<Option<Record>, Corrupt>) {
        const { assert!(S::SLOT_SIZE >= RECORD_LEN, "storage slots are too small") };
        let mut newest: Option<(u8, u32, Record)> = None;
        let mut blank = true;
        let mut buf = [0u8; RECORD_LEN];
        for slot in 0..2u8 {
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

    /// Writes `record` to the slot not holding the newest record.
    pub fn save<S: Storage>(
        &mut self,
        storage: &mut S,
        record: &Record,
    ) -> Result<(), StorageError> {
        let (slot, sequence) = match self.newest {
            Some((slot, sequence)) => (1 - slot, sequence.wrapping_add(1)),
            None => (0, 0),
        };
        let mut buf = [0u8; RECORD_LEN];
        let payload = record::encode(record, sequence, &mut buf).ok_or(StorageError::Encoding)?;
        if self.last_payload == Some(payload) {
            return Ok(());
        }
        storage.erase(slot)?;
        storage.write(slot, &buf)?;
        let mut check = [0u8; RECORD_LEN];
        storage.read(slot, &mut check)?;
        if check != buf {
            // The slot is not the newest: the last good record stays where it was.
            return Err(StorageError::ReadBack);
        }
        self.newest = Some((slot, sequence));
        self.last_payload = Some(payload);
        Ok(())
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

    #[test]
    fn newest_of_two_wins_and_writes_alternate() {
        let mut storage = RamStorage::new();
        let (mut journal, loaded) = Journal::load(&mut storage);
        assert_eq!(loaded, Ok(None));
        for key in 1..=5 {
            journal.save(&mut storage, &record(key)).unwrap();
            assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(key))));
        }
        assert_eq!(storage.writes(), 5);
        // Unchanged: not written again.
        journal.save(&mut storage, &record(5)).unwrap();
        assert_eq!(storage.writes(), 5);
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
            // The next write goes over the torn slot, not the good one.
            journal.save(&mut storage, &record(4)).unwrap();
            assert_eq!(Journal::load(&mut storage).1, Ok(Some(record(4))));
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
