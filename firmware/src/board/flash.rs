//! The persisted record in flash, written behind the core's back when no step can suffer.
//!
//! The core keeps configuration, key, Wi-Fi credentials and axis positions in its
//! two-slot record and writes it through [`Storage`] when motion stops (and on explicit
//! saves). Erasing a 4 KiB flash sector takes 45 ms (400 ms at worst) with interrupts
//! off and the flash unreadable, long enough to starve the step back-ends; so
//! [`FlashStorage`] keeps both slots in RAM, and [`writer`] copies a changed slot to flash
//! once every axis is idle (no move running or waiting, every queued pin change made).
//! An explicit save (`SaveConfig`, `SetKey`, ...) does not wait for it: the core, with
//! every axis idle, calls [`Storage::commit`], which writes to flash at once and answers
//! only after the read-back (or fails when pin changes are still being played out).
//! A slot is written whole (erase, program, read back), in the order the core wrote them,
//! so the journal's guarantee holds on flash: a power cut during a write leaves the other
//! slot's record intact. A write that fails is retried and counted ([`FAILED_WRITES`],
//! reported in `Status`); the status LED shows the fault.
//!
//! The motion mark lives in the watchdog's scratch registers ([`super::scratch`]). A mark
//! naming more axes is stored at once; one naming fewer (the record now holds their end
//! positions) is held back until the changed slots are in flash, and until then the
//! registers name both marks' axes.
//!
//! Layout: slot 0 in the sector at [`STORAGE_OFFSET`], slot 1 in the next one (the
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

const SLOTS: u8 = 2;
/// Where the two slots start: the last sectors of the board's flash (an offset into
/// flash, as the `STORAGE` region of the chip's memory map).
pub const STORAGE_OFFSET: u32 = (FLASH_SIZE - SLOTS as usize * ERASE_SIZE) as u32;

const _: () = assert!(RECORD_LEN <= ERASE_SIZE && RECORD_LEN.is_multiple_of(PAGE_SIZE));

pub type BoardFlash = Flash<'static, FLASH, Blocking, FLASH_SIZE>;

/// Record writes that failed on flash since start-up.
pub static FAILED_WRITES: AtomicU32 = AtomicU32::new(0);

/// Raised when a slot changed in RAM.
static CHANGED: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Both slots in RAM, mirrored to flash by [`writer`] or [`Storage::commit`].
pub struct FlashStorage {
    flash: BoardFlash,
    slots: [[u8; RECORD_LEN]; SLOTS as usize],
    dirty: [bool; SLOTS as usize],
    /// A mark naming fewer axes, stored once the dirty slots are in flash.
    held_mark: Option<[u8; MARK_LEN]>,
}

impl FlashStorage {
    /// Both slots as they are in flash (erased if unreadable).
    pub fn load(mut flash: BoardFlash) -> Self {
        let mut slots = [[0xFF; RECORD_LEN]; SLOTS as usize];
        for (slot, bytes) in (0u8..).zip(slots.iter_mut()) {
            if flash.blocking_read(offset(slot), bytes).is_err() {
                warn!("flash: slot {} unreadable", slot);
                bytes.fill(0xFF);
            }
        }
        Self {
            flash,
            slots,
            dirty: [false; SLOTS as usize],
            held_mark: None,
        }
    }

    fn slot(&mut self, slot: u8) -> Result<&mut [u8; RECORD_LEN], StorageError> {
        self.slots
            .get_mut(usize::from(slot))
            .ok_or(StorageError::OutOfRange)
    }

    fn touch(&mut self, slot: u8) {
        if let Some(dirty) = self.dirty.get_mut(usize::from(slot)) {
            *dirty = true;
            CHANGED.signal(());
        }
    }

    /// Writes every changed slot to flash, reading each back; a failure is counted.
    fn flush(&mut self) -> Result<(), StorageError> {
        let result = self.write_dirty();
        if let Err(error) = result {
            FAILED_WRITES.fetch_add(1, Ordering::Relaxed);
            warn!("flash: record write failed: {}", error);
        }
        result.map_err(|error| match error {
            embassy_rp::flash::Error::Other => StorageError::ReadBack,
            _ => StorageError::Device,
        })
    }

    fn write_dirty(&mut self) -> Result<(), embassy_rp::flash::Error> {
        let flash = &mut self.flash;
        for slot in 0..SLOTS {
            let index = usize::from(slot);
            if !self.dirty.get(index).copied().unwrap_or(false) {
                continue;
            }
            let Some(bytes) = self.slots.get(index) else {
                continue;
            };
            let at = offset(slot);
            flash.blocking_erase(at, at + ERASE_SIZE as u32)?;
            flash.blocking_write(at, bytes)?;
            let mut check = [0u8; RECORD_LEN];
            flash.blocking_read(at, &mut check)?;
            if check != *bytes {
                return Err(embassy_rp::flash::Error::Other);
            }
            if let Some(dirty) = self.dirty.get_mut(index) {
                *dirty = false;
            }
        }
        if let Some(mark) = self.held_mark.take() {
            scratch::write(&mark);
        }
        Ok(())
    }
}

impl Storage for FlashStorage {
    const SLOT_SIZE: usize = RECORD_LEN;

    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError> {
        let source = self.slot(slot)?;
        let source = source.get(..buf.len()).ok_or(StorageError::OutOfRange)?;
        buf.copy_from_slice(source);
        Ok(())
    }

    fn erase(&mut self, slot: u8) -> Result<(), StorageError> {
        self.slot(slot)?.fill(0xFF);
        self.touch(slot);
        Ok(())
    }

    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError> {
        let target = self.slot(slot)?;
        let target = target
            .get_mut(..data.len())
            .ok_or(StorageError::OutOfRange)?;
        // Programming flash only clears bits.
        for (byte, &new) in target.iter_mut().zip(data) {
            *byte &= new;
        }
        self.touch(slot);
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
        self.dirty.iter().any(|&dirty| dirty)
    }

    fn device_failures(&self) -> u32 {
        FAILED_WRITES.load(Ordering::Relaxed)
    }

    fn write_mark(&mut self, new: &[u8; MARK_LEN]) -> Result<(), StorageError> {
        if self.dirty.iter().any(|&dirty| dirty) {
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

fn offset(slot: u8) -> u32 {
    STORAGE_OFFSET + u32::from(slot) * ERASE_SIZE as u32
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
