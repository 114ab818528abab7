//! The controller: every piece of firmware state, the step loop and persistence.
//!
//! Requests are handled in [`crate::dispatch`]; this module owns the time-driven side:
//! [`Controller::poll`] makes the steps that fell due, finishes moves, powers coils up and
//! down, sets the motion mark before a move's first step and writes the record (then
//! shrinks the mark) when motion stops.

use heapless::{Deque, Vec};
use optalign_protocol::auth::Key;
use optalign_protocol::{
    AxisConfig, AxisStatus, BootRecord, Capabilities, Direction, Faults, MAX_AXES, MoveOutcome,
    Notification, PeerMessage, RequestId, SecurityCounters, SessionState, Status, StorageFailure,
    StorageHealth,
};

use crate::axis::Axis;
use crate::backoff::AuthBackoff;
use crate::config::{default_config, validate};
use crate::control::ControlClaim;
use crate::driver::StepDriver;
use crate::gear::{Gear, Travel};
use crate::mark;
use crate::motion::Move;
use crate::nonce::NonceIssuer;
use crate::outcomes::MoveLog;
use crate::path::effective_backlash;
use crate::record::{Record, WifiCredentials};
use crate::replay::ReplyCache;
use crate::session::{LinkKind, RngSource, Session};
use crate::slots::Journal;
use crate::storage::{Storage, StorageError};

/// Notifications held between a request and the next poll.
const OUTBOX_LEN: usize = 16;

/// Who the board is; reported in the handshake.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardInfo {
    pub board: &'static str,
    pub firmware_version: &'static str,
    pub board_id: u64,
    /// Axes driven (at most `MAX_AXES`).
    pub axes: u8,
    /// [`Capabilities`] bits.
    pub capabilities: u32,
}

/// Where an axis comes to rest when the motion in progress has run out.
#[derive(Clone, Copy)]
pub(crate) struct Rest {
    pub position: i32,
    pub gear: Gear,
}

/// The whole firmware state.
pub struct Controller<S: Storage> {
    pub(crate) info: BoardInfo,
    storage: S,
    journal: Journal,
    pub(crate) axes: Vec<Axis, MAX_AXES>,
    pub(crate) key: Option<Key>,
    /// Bumped by every new key, revoking earlier authentications.
    pub(crate) key_epoch: u32,
    /// Failed authentications, and the delay they impose on the next attempt.
    pub(crate) auth_backoff: AuthBackoff,
    /// Frames dropped by the seal check of authenticated sessions.
    pub(crate) rejected_frames: u32,
    pub(crate) wifi: Option<WifiCredentials>,
    /// The move being executed.
    pub(crate) active: Option<Move>,
    /// The move that starts when the active one has braked to a stop.
    pub(crate) pending: Option<Move>,
    pub(crate) replies: ReplyCache,
    /// How the latest moves ended, by request id.
    pub(crate) moves: MoveLog,
    outbox: Deque<Notification, OUTBOX_LEN>,
    pub(crate) emergency: bool,
    /// Which network session controls the motors (see [`crate::control`]).
    pub(crate) control: ControlClaim,
    /// Drawn at start-up; reported in the handshake.
    pub(crate) boot_nonce: u64,
    /// This boot's number: one more than the record's (see [`crate::nonce`]).
    boots: u32,
    /// Challenge nonces, issued once this boot's number is persisted.
    pub(crate) nonces: NonceIssuer,
    boot: BootRecord,
    /// The axes the motion mark in storage names (as last read or written).
    marked: u8,
    boot_us: u64,
    now_us: u64,
    persist_due: bool,
    storage_failures: u32,
    last_storage_failure: Option<StorageFailure>,
    /// The latest record write failed: what it held is not stored.
    save_failed: bool,
    /// Each axis's step engine underruns since start-up, as the embedder counts them.
    underruns: [u32; MAX_AXES],
}

impl<S: Storage> Controller<S> {
    /// Starts from the newest valid record in `storage`. A blank storage is a fresh board
    /// (defaults, positions 0, no fault, [`BootRecord::NoRecordYet`]); a storage whose
    /// records are all corrupt gives the defaults with `Faults::POSITION_LOST` on every
    /// axis; the axes the motion mark names (a reset during their move) are flagged
    /// `POSITION_LOST` too. Coils start off. `rng` draws the boot nonce.
    pub fn new(info: BoardInfo, mut storage: S, now_us: u64, rng: &mut dyn RngSource) -> Self {
        let capabilities = Capabilities(info.capabilities);
        let (journal, loaded) = Journal::load(&mut storage);
        // An unreadable mark is taken to name every axis.
        let marked = storage
            .read_mark()
            .map_or(u8::MAX, |bytes| mark::decode(&bytes));
        let mut axes = Vec::new();
        for index in 0..usize::from(info.axes).min(MAX_AXES) {
            let defaults = default_config(capabilities);
            let axis = match &loaded {
                Ok(Some(record)) => match record.axes.get(index) {
                    Some(saved) => {
                        let valid = u8::try_from(index)
                            .is_ok_and(|i| validate(i, &saved.config, capabilities).is_ok());
                        Axis::restore(saved, if valid { saved.config } else { defaults })
                    }
                    None => lost(defaults),
                },
                Err(_) => lost(defaults),
                Ok(None) => Axis::new(defaults),
            };
            let axis = if marked & bit(index) != 0 {
                lost_at(axis)
            } else {
                axis
            };
            let _ = axes.push(axis);
        }
        let boot = match (&loaded, marked) {
            (Err(_), _) => BootRecord::Unreadable,
            (Ok(_), 1..) => BootRecord::InterruptedMove,
            (Ok(None), 0) => BootRecord::NoRecordYet,
            (Ok(Some(_)), 0) => BootRecord::Restored,
        };
        let mut nonce = [0u8; 8];
        rng.fill(&mut nonce);
        let (key, wifi, boots) = match loaded {
            Ok(Some(record)) => (record.key, record.wifi, record.boots),
            Ok(None) | Err(_) => (None, None, 0),
        };
        Self {
            info,
            storage,
            journal,
            axes,
            key,
            key_epoch: 0,
            auth_backoff: AuthBackoff::default(),
            rejected_frames: 0,
            wifi,
            active: None,
            pending: None,
            replies: ReplyCache::new(),
            moves: MoveLog::new(),
            outbox: Deque::new(),
            emergency: false,
            control: ControlClaim::default(),
            boot_nonce: u64::from_le_bytes(nonce),
            boots: boots.wrapping_add(1),
            nonces: NonceIssuer::new(info.board_id),
            boot,
            marked,
            boot_us: now_us,
            now_us,
            persist_due: false,
            storage_failures: 0,
            last_storage_failure: None,
            save_failed: false,
            underruns: [0; MAX_AXES],
        }
    }

    pub fn storage(&self) -> &S {
        &self.storage
    }

    pub fn storage_mut(&mut self) -> &mut S {
        &mut self.storage
    }

    /// The configuration in force on `axis` (the board reads the driver kind from it).
    pub fn axis_config(&self, axis: u8) -> Option<&AxisConfig> {
        self.axes.get(usize::from(axis)).map(|a| &a.config)
    }

    /// Takes the underruns of each axis's step engine since start-up, as the embedder
    /// counts them (axis 0 first), for `Status`.
    pub fn record_underruns(&mut self, counts: &[u32]) {
        for (slot, &count) in self.underruns.iter_mut().zip(counts) {
            *slot = count;
        }
    }

    /// Whether a move is running or waiting to run.
    pub fn is_moving(&self) -> bool {
        self.active.is_some() || self.pending.is_some()
    }

    /// The stored Wi-Fi credentials, for the board to join its network.
    pub fn wifi(&self) -> Option<&WifiCredentials> {
        self.wifi.as_ref()
    }

    /// Whether any axis reports a fault (emergency stop latched, position lost, driver).
    pub fn has_faults(&self) -> bool {
        self.axes.iter().any(|a| a.faults.0 != 0)
    }

    /// Writes that failed since start-up, in the core or in the device (motion goes on
    /// regardless).
    pub fn storage_failures(&self) -> u32 {
        self.storage_failures
            .saturating_add(self.storage.device_failures())
    }

    /// Whether what was saved is durably stored, and how writes failed.
    pub fn storage_health(&self) -> StorageHealth {
        StorageHealth {
            unsaved: self.save_failed || self.persist_due || self.storage.unsaved(),
            failed_writes: self.storage_failures(),
            last_failure: self.last_storage_failure,
        }
    }

    /// Takes in the time of a call; time never goes back.
    pub(crate) fn observe(&mut self, now_us: u64) -> u64 {
        self.now_us = self.now_us.max(now_us);
        self.now_us
    }

    /// When the running move's last step falls due, `None` while idle. Step times are
    /// fixed at planning, so a simulation on instant time may poll once at this time and
    /// get every step of the move, in order.
    pub fn motion_end_us(&self) -> Option<u64> {
        self.active.as_ref().map(Move::end_us)
    }

    /// When `poll` must next run: at once when work is waiting, at the next step, at a
    /// move's start, or when idle coils are due to be released; `None` when nothing is.
    pub fn next_deadline_us(&self) -> Option<u64> {
        let immediate = !self.outbox.is_empty()
            || self.axes.iter().any(|a| a.cut_pending)
            || (self.persist_due && self.active.is_none());
        let motion = self.active.as_ref().map(|mv| {
            if mv.is_started() {
                mv.next_step_us().unwrap_or(self.now_us)
            } else {
                mv.start_us()
            }
        });
        let power_down = self
            .axes
            .iter()
            .filter(|a| a.powered)
            .filter_map(|a| a.power_down_at)
            .min();
        [immediate.then_some(self.now_us), motion, power_down]
            .into_iter()
            .flatten()
            .min()
    }

    /// Does everything due at or before `now_us`, in time order: delivers queued
    /// notifications, releases coils after an emergency stop, makes the due steps, finishes
    /// moves (`MoveFinished` to `out`), starts a replacing move, releases idle coils and
    /// writes the record once motion has stopped.
    pub fn poll(
        &mut self,
        now_us: u64,
        driver: &mut dyn StepDriver,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        let now = self.observe(now_us);
        while let Some(notification) = self.outbox.pop_front() {
            out(PeerMessage::Notify(notification));
        }
        for (index, axis) in (0u8..).zip(self.axes.iter_mut()) {
            if axis.cut_pending {
                axis.cut_pending = false;
                axis.powered = false;
                driver.set_power(index, false, axis.coil_steps);
            }
        }
        self.run_motion(now, driver, out);
        for (index, axis) in (0u8..).zip(self.axes.iter_mut()) {
            if axis.powered && axis.power_down_at.is_some_and(|t| t <= now) {
                axis.powered = false;
                axis.power_down_at = None;
                driver.set_power(index, false, axis.coil_steps);
            }
        }
        if self.persist_due && self.active.is_none() {
            self.persist_due = false;
            // A failure is counted; motion never depends on storage.
            let _ = self.persist();
        }
    }

    fn run_motion(
        &mut self,
        now: u64,
        driver: &mut dyn StepDriver,
        out: &mut dyn FnMut(PeerMessage),
    ) {
        loop {
            let Some(mv) = self.active.as_mut() else {
                return;
            };
            if !mv.is_started() {
                if mv.start_us() > now {
                    return;
                }
                mv.mark_started();
                let stepping: Vec<u8, MAX_AXES> = mv.stepping_axes().collect();
                // Before the first step: a reset from here on finds these axes marked.
                self.update_mark(Shrink::No);
                for index in stepping {
                    if let Some(axis) = self.axes.get_mut(usize::from(index)) {
                        axis.power_down_at = None;
                        if !axis.powered {
                            axis.powered = true;
                            driver.set_power(index, true, axis.coil_steps);
                        }
                    }
                }
                continue;
            }
            if let Some(due) = mv.take_due_run(now) {
                if let Some(axis) = self.axes.get_mut(usize::from(due.axis)) {
                    let (direction, coil_steps) = axis.steps(due.travel, due.steps);
                    driver.steps(due.axis, direction, due.steps, coil_steps);
                    axis.last_step_us = due.last_at_us;
                }
                continue;
            }
            if let Some(step) = mv.take_step(now) {
                if let Some(axis) = self.axes.get_mut(usize::from(step.axis)) {
                    let (direction, coil_steps) = axis.step(step.travel);
                    axis.last_step_us = step.at_us;
                    driver.step(step.axis, direction, coil_steps);
                }
                continue;
            }
            if !mv.is_finished() {
                return;
            }
            let (request, outcome) = (mv.request(), mv.outcome());
            let end = mv.end_us();
            let finished = self.finish_move(request, outcome);
            out(PeerMessage::Notify(finished));
            for axis in self
                .axes
                .iter_mut()
                .filter(|a| a.powered && a.power_down_at.is_none())
            {
                let idle_ms = axis.config.idle_power_down_ms;
                if idle_ms > 0 {
                    let since = axis.last_step_us.max(end);
                    axis.power_down_at = Some(since.saturating_add(u64::from(idle_ms) * 1000));
                }
            }
            self.active = self.pending.take();
            if self.active.is_none() {
                self.persist_due = true;
            }
        }
    }

    /// Records how the move started by `request` ended; returns the notification saying so.
    pub(crate) fn finish_move(&mut self, request: RequestId, outcome: MoveOutcome) -> Notification {
        let positions: Vec<i32, MAX_AXES> = self.axes.iter().map(|a| a.position).collect();
        self.moves.finished(request, outcome, positions.clone());
        Notification::MoveFinished {
            request,
            outcome,
            positions,
        }
    }

    /// Queues a notification for the next poll (the oldest is dropped when full).
    pub(crate) fn queue(&mut self, notification: Notification) {
        if let Err(notification) = self.outbox.push_back(notification) {
            self.outbox.pop_front();
            let _ = self.outbox.push_back(notification);
        }
    }

    /// Asks the next poll to write the record (once motion has stopped).
    pub(crate) fn persist_soon(&mut self) {
        self.persist_due = true;
    }

    /// Writes the record now (and reads it back), then shrinks the motion mark to the axes
    /// it cannot vouch for. On a board that writes flash in the background the record may
    /// still be queued: see [`Self::commit`].
    pub(crate) fn persist(&mut self) -> Result<(), StorageError> {
        let record = Record {
            key: self.key,
            wifi: self.wifi.clone(),
            axes: self.axes.iter().map(Axis::record).collect(),
            boots: self.boots,
        };
        let result = self.journal.save(&mut self.storage, &record);
        self.save_failed = result.is_err();
        match result {
            Ok(()) => self.update_mark(Shrink::Yes),
            Err(error) => self.count_failure(error),
        }
        result
    }

    /// Makes the record written by [`Self::persist`] durable now, read back; only while
    /// no axis moves (a board's flash write would starve the steps).
    pub(crate) fn commit(&mut self) -> Result<(), StorageError> {
        let result = self.storage.commit();
        if let Err(error) = result {
            self.count_failure(error);
        }
        result
    }

    /// Makes this boot's number durable before the first nonce of the boot is issued, so
    /// that no later boot can issue the same nonces (see [`crate::nonce`]).
    pub(crate) fn count_boot(&mut self) -> Result<(), StorageError> {
        if !self.nonces.is_counted() {
            self.persist()?;
            self.commit()?;
            self.nonces.counted(self.boots);
        }
        Ok(())
    }

    /// Counts a failed write (a write merely postponed is no failure).
    fn count_failure(&mut self, error: StorageError) {
        let failure = match error {
            StorageError::NotNow => return,
            StorageError::ReadBack => StorageFailure::ReadBack,
            StorageError::OutOfRange | StorageError::Device | StorageError::Encoding => {
                StorageFailure::Write
            }
        };
        self.storage_failures = self.storage_failures.saturating_add(1);
        self.last_storage_failure = Some(failure);
    }

    /// Axes whose saved position cannot be trusted: those flagged `POSITION_LOST`, and
    /// those of the motion running or waiting (bit `n` for axis `n`).
    fn untrusted_axes(&self) -> u8 {
        let lost = (0..)
            .zip(self.axes.iter())
            .filter(|(_, axis)| axis.faults.has(Faults::POSITION_LOST))
            .fold(0, |bits, (index, _)| bits | bit(index));
        [&self.active, &self.pending]
            .into_iter()
            .flatten()
            .flat_map(Move::axes)
            .fold(lost, |bits, axis| bits | bit(usize::from(axis)))
    }

    /// Writes the motion mark when the untrusted axes changed (a failure is counted). Only
    /// a written record vouches for an axis, so only then may the mark drop axes.
    fn update_mark(&mut self, shrink: Shrink) {
        let wanted = match shrink {
            Shrink::Yes => self.untrusted_axes(),
            Shrink::No => self.untrusted_axes() | self.marked,
        };
        if wanted == self.marked {
            return;
        }
        match self.storage.write_mark(&mark::encode(wanted)) {
            Ok(()) => self.marked = wanted,
            Err(error) => self.count_failure(error),
        }
    }

    /// Where each axis comes to rest once `motion` (a move already told to stop) has run out.
    pub(crate) fn rest_state(&self, motion: Option<&Move>) -> Vec<Rest, MAX_AXES> {
        (0u8..)
            .zip(self.axes.iter())
            .map(|(index, axis)| {
                let backlash = effective_backlash(&axis.config);
                let mut rest = Rest {
                    position: axis.position,
                    gear: axis.gear,
                };
                for leg in motion.map(|mv| mv.remaining(index)).unwrap_or_default() {
                    let (gear, load) = rest.gear.advance(leg.travel, leg.motor_steps, backlash);
                    let load = i32::try_from(load).unwrap_or(i32::MAX);
                    rest = Rest {
                        position: rest
                            .position
                            .saturating_add(load.saturating_mul(leg.travel.sign())),
                        gear,
                    };
                }
                rest
            })
            .collect()
    }

    /// Whether `axis` takes part in the running or the waiting move.
    pub(crate) fn axis_busy(&self, axis: u8) -> bool {
        [&self.active, &self.pending]
            .into_iter()
            .flatten()
            .any(|mv| mv.target(axis).is_some())
    }

    /// The state of the controller as `session` sees it.
    pub fn status(&self, session: &Session, now_us: u64) -> Status {
        let now = now_us.max(self.now_us);
        let axes = (0u8..)
            .zip(self.axes.iter())
            .map(|(index, axis)| {
                let moves = [&self.pending, &self.active];
                let target = moves
                    .iter()
                    .find_map(|mv| mv.as_ref().and_then(|mv| mv.target(index)))
                    .unwrap_or(axis.position);
                let moving = moves
                    .iter()
                    .flat_map(|mv| mv.iter())
                    .any(|mv| mv.stepping_axes().any(|a| a == index));
                let direction = match self.active.as_ref().and_then(|mv| mv.travel(index)) {
                    Some(Travel::Positive) => Direction::Positive,
                    Some(Travel::Negative) => Direction::Negative,
                    None => Direction::Idle,
                };
                AxisStatus {
                    position: axis.position,
                    motor_steps: axis.motor_steps,
                    target,
                    moving,
                    direction,
                    slack: axis.gear.slack(),
                    limits: axis.config.limits,
                    faults: axis.faults,
                    powered: axis.powered,
                    underruns: self.underruns.get(usize::from(index)).copied().unwrap_or(0),
                }
            })
            .collect();
        Status {
            axes,
            session: SessionState {
                trusted_link: session.link() == LinkKind::Serial,
                authenticated: self.is_authenticated(session),
                key_provisioned: self.key.is_some(),
            },
            emergency_stopped: self.emergency,
            uptime_ms: now.saturating_sub(self.boot_us) / 1000,
            boot: self.boot,
            storage: self.storage_health(),
            security: SecurityCounters {
                failed_authentications: self.auth_backoff.failures(),
                rejected_frames: self.rejected_frames,
            },
        }
    }

    /// When authentication attempts are accepted again after failures (in the past when
    /// they are accepted now); see `crate::backoff`.
    pub fn authentication_reopens_at_us(&self) -> u64 {
        self.auth_backoff.reopens_at_us()
    }

    pub(crate) fn is_authenticated(&self, session: &Session) -> bool {
        self.key.is_some() && session.authenticated == Some(self.key_epoch)
    }
}

/// Whether a mark update may drop axes.
#[derive(Clone, Copy)]
enum Shrink {
    Yes,
    No,
}

/// A fresh axis whose position could not be restored.
fn lost(config: AxisConfig) -> Axis {
    lost_at(Axis::new(config))
}

/// `axis` with its position flagged lost.
fn lost_at(mut axis: Axis) -> Axis {
    axis.faults.0 |= Faults::POSITION_LOST;
    axis
}

/// The mark bit of axis `index` (none beyond the eighth).
fn bit(index: usize) -> u8 {
    u32::try_from(index)
        .ok()
        .and_then(|i| 1u8.checked_shl(i))
        .unwrap_or(0)
}
