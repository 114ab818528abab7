//! The persisted record in flash, written behind the core's back when no step can suffer.
//!
//! The core keeps configuration, key, Wi-Fi credentials and axis positions in its record
//! journal, a ring of [`SLOTS`] 1 KiB slots over [`SECTORS`] 4 KiB sectors (`crate::slots`),
//! and writes it through [`Storage`] when motion stops (and on explicit saves). Erasing a
//! sector takes 45 ms (400 ms at worst) with interrupts off and the flash unreadable, long
//! enough to starve the step back-ends; so [`FlashStorage`] keeps the sector being
//! written in RAM (what the core erased and wrote of it), and [`writer`] copies it to
//! flash once every axis is idle (no move running or waiting, every queued pin change
//! made). An explicit save (`SaveConfig`, `SetKey`, ...) does not wait for it: the core,
//! with every axis idle, calls [`Storage::commit`], which writes to flash at once and
//! answers only after the read-back (or fails when pin changes are still being played
//! out). The sector is written as the core left it (erase if it erased it, then program
//! the slots it wrote, then read them back), so the journal's guarantee holds on flash:
//! a power cut during a write leaves the newest record before it intact. A write that
//! fails is retried and counted ([`FAILED_WRITES`], reported in `Status`); the status LED
//! shows the fault.
//!
//! Should the core move on to the next sector before the last one reached the flash (a
//! save while axes move, then another that fills the sector), the last one's writes are
//! dropped: they hold only records older than the new one, and the flash keeps what it
//! had, a consistent older state. The new sector is never the one holding the newest
//! record on flash (the ring has more than two sectors).
//!
//! The motion mark lives in the watchdog's scratch registers ([`super::scratch`]). A mark
//! naming more axes is stored at once; one naming fewer (the record now holds their end
//! positions) is held back until the written slots are in flash, and until then the
//! registers name both marks' axes.
//!
//! Layout: the ring starts at [`STORAGE_OFFSET`] and runs to the end of flash (the
//! `STORAGE` region of the chip's memory map, which the program is never linked into).

use embassy_rp::flash::{Blocking, ERASE_SIZE, Flash, PAGE_SIZE};
use embassy_rp::peripherals::FLASH;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::signal::Signal;
use embassy_time::Timer;
use portable_atomic::{AtomicU32, Ordering};

use super::events::LAST_EVENT_US;
use super::log::{info, warn};
use super::scratch;
use super::this::FLASH_SIZE;
use super::{SharedCore, now_us};
use crate::mark::{self, MARK_LEN};
use crate::record::RECORD_LEN;
use crate::storage::{Storage, StorageError};

/// Sectors in the ring: 240 KiB at the end of flash.
pub const SECTORS: usize = 60;
/// Slots in a sector.
const PER_SECTOR: usize = ERASE_SIZE / RECORD_LEN;
/// Slots in the ring.
pub const SLOTS: usize = SECTORS * PER_SECTOR;
/// Where the ring starts: the last sectors of the board's flash (an offset into flash, as
/// the `STORAGE` region of the chip's memory map).
pub const STORAGE_OFFSET: u32 = (FLASH_SIZE - SECTORS * ERASE_SIZE) as u32;

const _: () =
    assert!(RECORD_LEN.is_multiple_of(PAGE_SIZE) && ERASE_SIZE.is_multiple_of(RECORD_LEN));
const _: () = assert!(SLOTS <= u8::MAX as usize);

pub type BoardFlash = Flash<'static, FLASH, Blocking, FLASH_SIZE>;

/// Record writes that failed on flash since start-up.
pub static FAILED_WRITES: AtomicU32 = AtomicU32::new(0);

/// Raised when the sector in RAM changed.
static CHANGED: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// The sector the core is writing, as it will be on flash.
struct OpenSector {
    sector: usize,
    image: [u8; ERASE_SIZE],
    /// The core erased it: erase it on flash before programming.
    erase: bool,
    /// Slots the core wrote since the last flush.
    written: [bool; PER_SECTOR],
}

/// The ring on flash, with the sector being written in RAM until [`writer`] or
/// [`Storage::commit`] copies it to flash.
pub struct FlashStorage {
    flash: BoardFlash,
    open: Option<OpenSector>,
    /// A mark naming fewer axes, stored once the written slots are in flash.
    held_mark: Option<[u8; MARK_LEN]>,
}

impl FlashStorage {
    /// The ring on `flash`, nothing written yet.
    pub fn new(flash: BoardFlash) -> Self {
        Self {
            flash,
            open: None,
            held_mark: None,
        }
    }

    /// The open sector for `slot`, opened as it is on flash (`erased`: as erased) when
    /// another one, or none, was open.
    fn open(&mut self, slot: u8, erased: bool) -> Result<&mut OpenSector, StorageError> {
        let slot = usize::from(slot);
        if slot >= SLOTS {
            return Err(StorageError::OutOfRange);
        }
        let sector = slot / PER_SECTOR;
        let reuse = self.open.as_ref().is_some_and(|open| open.sector == sector);
        if !reuse {
            if self.open.as_ref().is_some_and(OpenSector::unsaved) {
                warn!("flash: sector superseded before it was written");
            }
            let mut image = [0xFF; ERASE_SIZE];
            if !erased
                && self
                    .flash
                    .blocking_read(sector_offset(sector), &mut image)
                    .is_err()
            {
                return Err(StorageError::Device);
            }
            self.open = Some(OpenSector {
                sector,
                image,
                erase: false,
                written: [false; PER_SECTOR],
            });
        }
        self.open.as_mut().ok_or(StorageError::Device)
    }

    /// Writes the open sector to flash as the core left it, reading the slots back; a
    /// failure is counted.
    fn flush(&mut self) -> Result<(), StorageError> {
        let result = self.write_open();
        if let Err(error) = result {
            FAILED_WRITES.fetch_add(1, Ordering::Relaxed);
            warn!("flash: record write failed: {}", error);
        }
        result.map_err(|error| match error {
            embassy_rp::flash::Error::Other => StorageError::ReadBack,
            _ => StorageError::Device,
        })
    }

    fn write_open(&mut self) -> Result<(), embassy_rp::flash::Error> {
        let flash = &mut self.flash;
        if let Some(open) = self.open.as_mut().filter(|open| open.unsaved()) {
            let at = sector_offset(open.sector);
            if open.erase {
                flash.blocking_erase(at, at + ERASE_SIZE as u32)?;
                open.erase = false;
            }
            for (index, slot) in open.image.chunks(RECORD_LEN).enumerate() {
                if !open.written.get(index).copied().unwrap_or(false) {
                    continue;
                }
                let slot_at = at + (index * RECORD_LEN) as u32;
                flash.blocking_write(slot_at, slot)?;
                let mut check = [0u8; RECORD_LEN];
                flash.blocking_read(slot_at, &mut check)?;
                if check != slot {
                    return Err(embassy_rp::flash::Error::Other);
                }
                if let Some(written) = open.written.get_mut(index) {
                    *written = false;
                }
            }
        }
        if let Some(mark) = self.held_mark.take() {
            scratch::write(&mark);
        }
        Ok(())
    }
}

impl OpenSector {
    fn unsaved(&self) -> bool {
        self.erase || self.written.iter().any(|&written| written)
    }

    fn slot(&mut self, slot: u8) -> Result<&mut [u8], StorageError> {
        let start = usize::from(slot) % PER_SECTOR * RECORD_LEN;
        self.image
            .get_mut(start..start + RECORD_LEN)
            .ok_or(StorageError::OutOfRange)
    }
}

impl Storage for FlashStorage {
    const SLOT_SIZE: usize = RECORD_LEN;
    const SLOTS: u8 = SLOTS as u8;
    const SLOTS_PER_SECTOR: u8 = PER_SECTOR as u8;

    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError> {
        let index = usize::from(slot);
        if index >= SLOTS || buf.len() > RECORD_LEN {
            return Err(StorageError::OutOfRange);
        }
        match self
            .open
            .as_mut()
            .filter(|open| open.sector == index / PER_SECTOR)
        {
            Some(open) => buf.copy_from_slice(&open.slot(slot)?[..buf.len()]),
            None => {
                let at =
                    sector_offset(index / PER_SECTOR) + (index % PER_SECTOR * RECORD_LEN) as u32;
                self.flash
                    .blocking_read(at, buf)
                    .map_err(|_| StorageError::Device)?;
            }
        }
        Ok(())
    }

    fn erase(&mut self, slot: u8) -> Result<(), StorageError> {
        let open = self.open(slot, true)?;
        open.image.fill(0xFF);
        open.erase = true;
        open.written = [false; PER_SECTOR];
        CHANGED.signal(());
        Ok(())
    }

    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError> {
        let open = self.open(slot, false)?;
        let target = open.slot(slot)?;
        let target = target
            .get_mut(..data.len())
            .ok_or(StorageError::OutOfRange)?;
        // Programming flash only clears bits.
        for (byte, &new) in target.iter_mut().zip(data) {
            *byte &= new;
        }
        if let Some(written) = open.written.get_mut(usize::from(slot) % PER_SECTOR) {
            *written = true;
        }
        CHANGED.signal(());
        Ok(())
    }

    fn read_mark(&mut self) -> Result<[u8; MARK_LEN], StorageError> {
        Ok(scratch::read())
    }

    fn commit(&mut self) -> Result<(), StorageError> {
        if now_us() <= LAST_EVENT_US.load(Ordering::Acquire) + 100 {
            return Err(StorageError::NotNow);
        }
        self.flush()
    }

    fn unsaved(&self) -> bool {
        self.open.as_ref().is_some_and(OpenSector::unsaved)
    }

    fn device_failures(&self) -> u32 {
        FAILED_WRITES.load(Ordering::Relaxed)
    }

    fn write_mark(&mut self, new: &[u8; MARK_LEN]) -> Result<(), StorageError> {
        if self.unsaved() {
            let held = mark::decode(&scratch::read()) | mark::decode(new);
            scratch::write(&mark::encode(held));
            self.held_mark = Some(*new);
        } else {
            scratch::write(new);
            self.held_mark = None;
        }
        Ok(())
    }
}

fn sector_offset(sector: usize) -> u32 {
    STORAGE_OFFSET + (sector * ERASE_SIZE) as u32
}

/// What one attempt to write the changed slots came to.
enum Attempt {
    Written,
    Moving,
    Failed,
}

/// Copies changed slots to flash whenever the axes are idle.
#[embassy_executor::task]
pub async fn writer(core: &'static SharedCore) -> ! {
    loop {
        CHANGED.wait().await;
        loop {
            // One critical section from the idle check to the end of the write: no
            // request can start a move in between.
            let attempt = core.lock(|cell| {
                let mut core = cell.borrow_mut();
                let played_out = now_us() > LAST_EVENT_US.load(Ordering::Acquire) + 100;
                if core.is_moving() || !played_out {
                    return Attempt::Moving;
                }
                if !core.storage().unsaved() {
                    return Attempt::Written;
                }
                match core.storage_mut().flush() {
                    Ok(()) => Attempt::Written,
                    Err(_) => Attempt::Failed,
                }
            });
            match attempt {
                Attempt::Written => {
                    info!("flash: record written");
                    break;
                }
                Attempt::Moving => Timer::after_millis(20).await,
                Attempt::Failed => Timer::after_secs(1).await,
            }
        }
    }
}
