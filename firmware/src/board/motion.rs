//! The motion task: runs the core's time-driven side a fixed lookahead ahead of real time.
//!
//! On every wake-up it polls the core at each deadline up to `now + LOOKAHEAD_US`, each at
//! its exact time, so the step engine ([`super::pio_steps`]) receives every pin change
//! [`LOOKAHEAD_US`] before it is due and times it in hardware, unaffected by anything the
//! CPU does meanwhile; at the end of each round it hands the engine's words to the DMA,
//! and at the start of each it reads the engine's underruns into the core (`Status`).
//! It then polls once at that horizon, which moves the core's clock there, and the links
//! hand requests to the core at the horizon too: whatever a request plans next starts
//! after everything already queued, so queued steps are never taken back and positions
//! stay exact, and even a move's first pin change is queued ahead of its time. What that
//! means, each bounded by the lookahead:
//! - a move starts, and an emergency stop cuts the coils, 2 ms after the request (after
//!   the steps already queued);
//! - notifications are held until their time has come in real time, so `MoveFinished`
//!   never arrives before the last step has been made;
//! - `Status` describes the state at the horizon.
//!
//! The task runs alone on the high-priority interrupt executor, above everything but the
//! time driver's alarm; requests wake it through [`WAKE`] so a new move or an emergency
//! stop is acted on at once. Its one deadline: to run again before the words it handed
//! over have been played, [`LOOKAHEAD_US`] after it ran; it runs every
//! [`MOVING_TICK_US`] while a move runs.

use embassy_futures::select::select;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::pubsub::PubSubChannel;
use embassy_sync::signal::Signal;
use embassy_time::{Instant, Timer};
use heapless::Deque;
use optalign_protocol::{Notification, PeerMessage};
use portable_atomic::{AtomicBool, Ordering};

use super::events::EventSink;
use super::link::MAX_SESSIONS;
use super::{SharedCore, now_us, watchdog};

/// How far ahead of real time the core runs.
pub const LOOKAHEAD_US: u64 = 2_000;

/// Wake-up period while a move runs (keeps the step engine's words ahead of it).
const MOVING_TICK_US: u64 = LOOKAHEAD_US / 2;

/// Wake-up period when idle (the watchdog check-in).
const IDLE_TICK_US: u64 = 100_000;

/// Polls per lock of the core before checking the time again.
const POLLS_PER_ROUND: usize = 64;

/// Notifications waiting for their time.
const HELD: usize = 16;

/// Set by the links after each request: deadlines may have changed.
pub static WAKE: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// A move is running or waiting to run.
pub static ENGAGED: AtomicBool = AtomicBool::new(false);

/// An axis reports a fault (for the status LED).
pub static FAULT: AtomicBool = AtomicBool::new(false);

/// Notifications for every session.
pub static NOTES: PubSubChannel<CriticalSectionRawMutex, Notification, 8, MAX_SESSIONS, 1> =
    PubSubChannel::new();

#[embassy_executor::task]
pub async fn run(core: &'static SharedCore, mut sink: EventSink) -> ! {
    let mut held: Deque<(u64, Notification), HELD> = Deque::new();
    let publisher = NOTES.immediate_publisher();
    let mut clock = now_us();
    loop {
        watchdog::check_in(watchdog::MOTION);
        let underruns = sink.engine().check();
        let horizon = now_us().saturating_add(LOOKAHEAD_US).max(clock);
        let mut polls = 0;
        while clock < horizon && polls < POLLS_PER_ROUND {
            polls += 1;
            core.lock(|cell| {
                let mut core = cell.borrow_mut();
                let at = match core.next_deadline_us() {
                    Some(deadline) if deadline < horizon => deadline.max(clock),
                    _ => horizon,
                };
                sink.prepare(at, &core);
                core.poll(at, &mut sink, &mut |message| {
                    if let PeerMessage::Notify(note) = message
                        && let Err(note) = held.push_back((at, note))
                    {
                        // Full: deliver at once rather than lose it.
                        publisher.publish_immediate(note.1);
                    }
                });
                clock = at;
            });
        }
        let (deadline, moving) = core.lock(|cell| {
            let mut core = cell.borrow_mut();
            core.record_underruns(&underruns);
            FAULT.store(core.has_faults(), Ordering::Relaxed);
            (core.next_deadline_us(), core.is_moving())
        });
        ENGAGED.store(moving, Ordering::Release);
        // Every change before `clock` is queued: pad up to it while a move runs.
        sink.engine().commit(clock, moving);
        let now = now_us();
        while let Some(&(at, _)) = held.front()
            && at <= now
        {
            if let Some((_, note)) = held.pop_front() {
                publisher.publish_immediate(note);
            }
        }
        let tick = if moving { MOVING_TICK_US } else { IDLE_TICK_US };
        let wake = [
            deadline.map(|d| d.saturating_sub(LOOKAHEAD_US)),
            held.front().map(|&(at, _)| at),
            Some(now.saturating_add(tick)),
        ]
        .into_iter()
        .flatten()
        .min()
        .unwrap_or(now);
        select(Timer::at(Instant::from_micros(wake)), WAKE.wait()).await;
    }
}
