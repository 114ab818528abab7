//! The simulated bench: what outlives the controller when its power is cut.
//!
//! The mounts keep their shafts where the last step left them; the flash chip keeps
//! whatever was last written, a write cut short stays torn. A [`SimPeer`] killed in
//! process hands its bench on ([`Bench::power_cycled`]) to the next start-up; a peer
//! process with state files saves the mounts and the flash apart, mounts first, so a
//! process killed at any instant leaves the two files as a power cut leaves a bench.
//!
//! For the kill campaign the bench can also keep a log of the moves the controller really
//! started and finished, check every `Status` the controller gives against the true
//! shafts, and cut the power in the middle of a flash write (each only when asked to).
//!
//! [`SimPeer`]: super::SimPeer

use std::collections::HashMap;
use std::sync::{Arc, Mutex, MutexGuard};

use optalign_firmware::sim::SimDriver;
use optalign_firmware::{RamStorage, StepDirection, StepDriver, Storage, StorageError};
use optalign_protocol::{Faults, MoveOutcome, Status};

use super::state_file::StateFiles;

/// The mounts, the flash chip and their files.
pub struct Bench {
    mounts: SimDriver,
    flash: RamStorage,
    files: Option<StateFiles>,
    log: Option<ExecutionLog>,
    audit: Option<PositionAudit>,
    /// A power cut armed for a coming slot write: (writes to let through, bytes kept).
    cut_in_write: Option<(u32, usize)>,
}

impl Bench {
    /// A bench of `mounts` and `flash`, saved to `files` when given.
    pub fn new(mounts: SimDriver, flash: RamStorage, files: Option<StateFiles>) -> Self {
        Self {
            mounts,
            flash,
            files,
            log: None,
            audit: None,
            cut_in_write: None,
        }
    }

    /// The bench as the next start-up finds it after a power cut: the shafts where they
    /// are, the coils off, the flash as last written (writable again), the logs kept.
    pub fn power_cycled(&self) -> Self {
        let axes = (0u8..).map_while(|axis| self.mounts.mount(axis).cloned());
        Self {
            mounts: SimDriver::new(axes),
            flash: self.flash.power_cycled(),
            files: self.files.clone(),
            log: self.log.clone(),
            audit: self.audit.clone(),
            cut_in_write: None,
        }
    }

    pub fn mounts(&self) -> &SimDriver {
        &self.mounts
    }

    pub fn flash(&self) -> &RamStorage {
        &self.flash
    }

    /// True shaft positions of the mounts (what the mirrors see), in steps.
    pub fn shaft_positions(&self) -> Vec<i32> {
        (0u8..)
            .map_while(|axis| self.mounts.mount(axis))
            .map(|mount| mount.mirror_position())
            .collect()
    }

    /// Whether the power failed in a torn write (nothing more is stored).
    pub fn power_failed(&self) -> bool {
        self.flash.power_failed()
    }

    /// Cuts the power in a coming slot write: `writes` later writes pass whole, the next
    /// one stores its first `bytes` bytes and nothing is stored after it.
    pub fn cut_power_in_write(&mut self, writes: u32, bytes: usize) {
        self.cut_in_write = Some((writes, bytes));
    }

    /// Logs every move started and how it ended from now on, over every start-up on this
    /// bench (for tests: the log grows with every move).
    pub fn keep_log(&mut self) {
        self.log.get_or_insert_with(ExecutionLog::default);
    }

    /// The moves started and finished, if the log is kept.
    pub fn log(&self) -> Option<&ExecutionLog> {
        self.log.as_ref()
    }

    pub(crate) fn log_mut(&mut self) -> Option<&mut ExecutionLog> {
        self.log.as_mut()
    }

    /// Checks every `Status` from now on against the true shafts: a position that differs
    /// must carry `POSITION_LOST`. Meaningful only for ideal mounts (no dead band, no lost
    /// steps), whose shafts follow the motor exactly.
    pub fn audit_positions(&mut self) {
        self.audit.get_or_insert_with(PositionAudit::default);
    }

    /// What the position audit found, if it runs.
    pub fn audit(&self) -> Option<&PositionAudit> {
        self.audit.as_ref()
    }

    pub(crate) fn check_status(&mut self, status: &Status) {
        let shafts = self.shaft_positions();
        let Some(audit) = &mut self.audit else {
            return;
        };
        audit.checked += 1;
        for (axis, (state, shaft)) in status.axes.iter().zip(shafts).enumerate() {
            if state.position != shaft && !state.faults.has(Faults::POSITION_LOST) {
                audit.unflagged.push(format!(
                    "axis {axis}: reported {} unflagged, the shaft is at {shaft}",
                    state.position
                ));
            }
        }
    }

    /// Saves the mounts to their file when they changed (physical state comes first).
    pub(crate) fn save_mounts(&mut self) -> anyhow::Result<()> {
        match &mut self.files {
            Some(files) => files.save_mounts(&self.mounts),
            None => Ok(()),
        }
    }

    /// Saves the mounts, then the flash image; a failure is the device failing the write
    /// (the controller answers it as a storage error and counts it in `Status`).
    fn save_flash(&mut self) -> Result<(), StorageError> {
        let Some(files) = &mut self.files else {
            return Ok(());
        };
        let saved = files
            .save_mounts(&self.mounts)
            .and_then(|()| files.save_flash(self.flash.as_bytes()));
        saved.map_err(|error| {
            tracing::error!(%error, "cannot write the peer's flash file");
            StorageError::Device
        })
    }
}

/// Moves the controller really started and how they ended, by request id.
#[derive(Clone, Debug, Default)]
pub struct ExecutionLog {
    starts: HashMap<u32, u32>,
    finishes: HashMap<u32, (MoveOutcome, Vec<i32>)>,
}

impl ExecutionLog {
    pub(crate) fn started(&mut self, request: u32) {
        *self.starts.entry(request).or_default() += 1;
    }

    pub(crate) fn finished(&mut self, request: u32, outcome: MoveOutcome, positions: Vec<i32>) {
        self.finishes.insert(request, (outcome, positions));
    }

    /// How many times the move of `request` was started.
    pub fn starts(&self, request: u32) -> u32 {
        self.starts.get(&request).copied().unwrap_or(0)
    }

    /// Moves started in all.
    pub fn total_starts(&self) -> usize {
        self.starts.values().map(|&n| n as usize).sum()
    }

    /// Request ids whose move was started more than once.
    pub fn started_twice(&self) -> Vec<u32> {
        let mut twice: Vec<u32> = (self.starts.iter())
            .filter(|&(_, &count)| count > 1)
            .map(|(&id, _)| id)
            .collect();
        twice.sort_unstable();
        twice
    }

    /// How the move of `request` ended and the positions then, if it ended.
    pub fn finish(&self, request: u32) -> Option<&(MoveOutcome, Vec<i32>)> {
        self.finishes.get(&request)
    }
}

/// `Status` replies checked against the true shafts.
#[derive(Clone, Debug, Default)]
pub struct PositionAudit {
    pub checked: u64,
    /// Positions that differed from the shaft without `POSITION_LOST`.
    pub unflagged: Vec<String>,
}

/// The bench shared between a controller and whoever keeps it across power cuts.
pub type SharedBench = Arc<Mutex<Bench>>;

pub(crate) fn lock(bench: &Mutex<Bench>) -> MutexGuard<'_, Bench> {
    bench
        .lock()
        .unwrap_or_else(|poisoned| poisoned.into_inner())
}

/// The controller's flash: the bench's chip, written through to the flash file.
pub struct FlashPort(pub SharedBench);

impl FlashPort {
    fn write_through(
        &mut self,
        change: impl FnOnce(&mut RamStorage) -> Result<(), StorageError>,
    ) -> Result<(), StorageError> {
        let mut bench = lock(&self.0);
        change(&mut bench.flash)?;
        bench.save_flash()
    }
}

impl Storage for FlashPort {
    const SLOT_SIZE: usize = RamStorage::SLOT_SIZE;
    const SLOTS: u8 = RamStorage::SLOTS;
    const SLOTS_PER_SECTOR: u8 = RamStorage::SLOTS_PER_SECTOR;

    fn read(&mut self, slot: u8, buf: &mut [u8]) -> Result<(), StorageError> {
        lock(&self.0).flash.read(slot, buf)
    }

    fn erase(&mut self, slot: u8) -> Result<(), StorageError> {
        self.write_through(|flash| flash.erase(slot))
    }

    fn write(&mut self, slot: u8, data: &[u8]) -> Result<(), StorageError> {
        {
            let mut bench = lock(&self.0);
            match bench.cut_in_write {
                Some((0, bytes)) => {
                    bench.cut_in_write = None;
                    bench.flash.tear_next_write(bytes);
                }
                Some((writes, bytes)) => bench.cut_in_write = Some((writes - 1, bytes)),
                None => {}
            }
        }
        self.write_through(|flash| flash.write(slot, data))
    }

    fn read_mark(&mut self) -> Result<[u8; optalign_firmware::mark::MARK_LEN], StorageError> {
        lock(&self.0).flash.read_mark()
    }

    fn write_mark(
        &mut self,
        mark: &[u8; optalign_firmware::mark::MARK_LEN],
    ) -> Result<(), StorageError> {
        self.write_through(|flash| flash.write_mark(mark))
    }
}

/// The controller's step outputs: the bench's mounts.
pub struct MountsPort<'a>(pub &'a Mutex<Bench>);

impl StepDriver for MountsPort<'_> {
    fn step(&mut self, axis: u8, direction: StepDirection, motor_steps: i32) {
        lock(self.0).mounts.step(axis, direction, motor_steps);
    }

    fn steps(&mut self, axis: u8, direction: StepDirection, count: u32, motor_steps: i32) {
        lock(self.0)
            .mounts
            .steps(axis, direction, count, motor_steps);
    }

    fn set_power(&mut self, axis: u8, on: bool, motor_steps: i32) {
        lock(self.0).mounts.set_power(axis, on, motor_steps);
    }
}
