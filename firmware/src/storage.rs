//! Persistent storage of fixed-size slots and the motion mark, and an in-memory
//! implementation.
//!
//! The record journal (`crate::slots`) uses a ring of slots of at least [`RECORD_LEN`]
//! bytes each, grouped in erase sectors: on flash `erase` clears a whole sector, and
//! `write` programs into an erased slot. The motion mark (see [`crate::mark`]) lives apart
//! from the slots, where it can be set without holding up a move.

use crate::mark::MARK_LEN;
use crate::record::RECORD_LEN;

/// Why a storage operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StorageError {
    /// The slot number or length is outside the device.
    OutOfRange,
    /// The device reported a failure.
    Device,
    /// The record did not serialise into a slot (a bug if it ever appears).
    Encoding,
    /// The write reported success, but reading it back gave other bytes.
    ReadBack,
    /// The device cannot write now (the board: the last steps are still being played
    /// out); the write stays queued.
    NotNow,
}

impl StorageError {
    /// A short description, for error replies.
    pub fn describe(self) -> &'static str {
        match self {
            Self::OutOfRange => "slot out of range",
            Self::Device => "the device failed the write",
            Self::Encoding => "the record does not encode",
            Self::ReadBack => "reading it back gave other bytes",
            Self::NotNow => "steps still being played out, the write is queued",
        }
    }
}

/// Fixed-size slots of non-volatile memory, in erase sectors of
/// [`SLOTS_PER_SECTOR`](Self::SLOTS_PER_SECTOR) slots.
pub trait Storage {
    /// Bytes per slot.
    const SLOT_SIZE: usize;
    /// Slots in all (a multiple of [`Self::SLOTS_PER_SECTOR`], at least three sectors).
    const SLOTS: u8;
    /// Slots erased together.
    const SLOTS_PER_SECTOR: u8;
    /// Reads the first `buf.len()` bytes of `slot`.
    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError>;
    /// Erases the sector holding `slot` (every slot of it, to 0xFF).
    fn erase(&mut self, slot: u8) -> Result<(), StorageError>;
    /// Programs `data` at the start of the erased `slot`.
    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError>;
    /// Reads the motion mark.
    fn read_mark(&mut self) -> Result<[u8; MARK_LEN], StorageError>;
    /// Replaces the motion mark. A mark naming more axes than the one in force holds from
    /// the moment this returns; one naming fewer may wait until the slot writes made
    /// before it are durable, and never takes effect before them.
    fn write_mark(&mut self, mark: &[u8; MARK_LEN]) -> Result<(), StorageError>;
    /// Makes every slot write so far durable, reading each back; called only while no axis
    /// moves. Storage that writes through at once (the default) has nothing to do.
    fn commit(&mut self) -> Result<(), StorageError> {
        Ok(())
    }
    /// Whether slot writes are waiting to be made durable.
    fn unsaved(&self) -> bool {
        false
    }
    /// Writes that failed in the device itself, behind the core's back (a board writing
    /// in the background counts them here).
    fn device_failures(&self) -> u32 {
        0
    }
}

/// Slots and the mark in RAM, three sectors of two slots: for tests and the simulated
/// peer, which saves [`Self::as_bytes`] to a file and restores it with
/// [`Self::from_bytes`]. It can fail on demand, store writes wrongly while reporting
/// success, and simulate a power loss in the middle of a write.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RamStorage {
    /// The slots in order, then the mark.
    bytes: [u8; RAM_SLOTS * RECORD_LEN + MARK_LEN],
    tear_after: Option<usize>,
    /// Power failed in a torn write: nothing is stored any more.
    dead: bool,
    failing: bool,
    corrupting: bool,
    writes: u32,
    erases: u32,
}

/// [`RamStorage`]'s slots.
const RAM_SLOTS: usize = 6;
/// Where [`RamStorage`] keeps the mark.
const MARK_AT: usize = RAM_SLOTS * RECORD_LEN;

impl Default for RamStorage {
    fn default() -> Self {
        Self::new()
    }
}

impl RamStorage {
    /// Every slot erased, as on a fresh board.
    pub fn new() -> Self {
        Self {
            bytes: [0xFF; RAM_SLOTS * RECORD_LEN + MARK_LEN],
            tear_after: None,
            dead: false,
            failing: false,
            corrupting: false,
            writes: 0,
            erases: 0,
        }
    }

    /// Storage holding `bytes` (as saved from [`Self::as_bytes`]); missing bytes are erased,
    /// extra bytes ignored.
    pub fn from_bytes(bytes: &[u8]) -> Self {
        let mut storage = Self::new();
        let len = bytes.len().min(storage.bytes.len());
        storage.bytes[..len].copy_from_slice(&bytes[..len]);
        storage
    }

    /// The contents as a controller started after a power cut finds them (writing works
    /// again).
    pub fn power_cycled(&self) -> Self {
        Self::from_bytes(self.as_bytes())
    }

    /// The raw contents of the slots and the mark.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The raw contents, writable (to corrupt a record in a test).
    pub fn as_bytes_mut(&mut self) -> &mut [u8] {
        &mut self.bytes
    }

    /// The next write stores only its first `bytes` bytes, as if power failed there:
    /// nothing written after it (slots or mark) is stored, until [`Self::power_cycled`].
    pub fn tear_next_write(&mut self, bytes: usize) {
        self.tear_after = Some(bytes);
    }

    /// Whether the power failed in a torn write (nothing is stored until
    /// [`Self::power_cycled`]).
    pub fn power_failed(&self) -> bool {
        self.dead
    }

    /// Makes every erase and write fail (or succeed again).
    pub fn set_failing(&mut self, failing: bool) {
        self.failing = failing;
    }

    /// Makes every slot write report success but store its first byte inverted (or
    /// store faithfully again), as a worn flash cell would.
    pub fn set_corrupting(&mut self, corrupting: bool) {
        self.corrupting = corrupting;
    }

    /// Completed (or torn) writes so far.
    pub fn writes(&self) -> u32 {
        self.writes
    }

    /// Sector erases so far.
    pub fn erases(&self) -> u32 {
        self.erases
    }

    fn slot(&mut self, slot: u8) -> Result<&mut [u8], StorageError> {
        let start = usize::from(slot) * RECORD_LEN;
        self.bytes
            .get_mut(start..start + RECORD_LEN)
            .ok_or(StorageError::OutOfRange)
    }
}

impl Storage for RamStorage {
    const SLOT_SIZE: usize = RECORD_LEN;
    const SLOTS: u8 = RAM_SLOTS as u8;
    const SLOTS_PER_SECTOR: u8 = 2;

    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError> {
        let src = self
            .slot(slot)?
            .get(..buf.len())
            .ok_or(StorageError::OutOfRange)?;
        buf.copy_from_slice(src);
        Ok(())
    }

    fn erase(&mut self, slot: u8) -> Result<(), StorageError> {
        if self.failing {
            return Err(StorageError::Device);
        }
        let first = slot - slot % Self::SLOTS_PER_SECTOR;
        for slot in first..first + Self::SLOTS_PER_SECTOR {
            if !self.dead {
                self.slot(slot)?.fill(0xFF);
            }
        }
        self.erases += 1;
        Ok(())
    }

    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError> {
        if self.failing {
            return Err(StorageError::Device);
        }
        if self.dead {
            return Ok(());
        }
        let torn = self.tear_after.take();
        let corrupting = self.corrupting;
        let keep = torn.unwrap_or(data.len()).min(data.len());
        let dst = self
            .slot(slot)?
            .get_mut(..data.len())
            .ok_or(StorageError::OutOfRange)?;
        dst[..keep].copy_from_slice(&data[..keep]);
        if corrupting && let Some(first) = dst.first_mut() {
            *first = !*first;
        }
        self.writes += 1;
        self.dead = torn.is_some();
        Ok(())
    }

    fn read_mark(&mut self) -> Result<[u8; MARK_LEN], StorageError> {
        let mut mark = [0xFF; MARK_LEN];
        mark.copy_from_slice(&self.bytes[MARK_AT..]);
        Ok(mark)
    }

    fn write_mark(&mut self, mark: &[u8; MARK_LEN]) -> Result<(), StorageError> {
        if self.failing {
            return Err(StorageError::Device);
        }
        if !self.dead {
            self.bytes[MARK_AT..].copy_from_slice(mark);
        }
        Ok(())
    }
}
