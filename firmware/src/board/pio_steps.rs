//! Step timing by PIO: one state machine per axis plays the axis's event queue out with
//! cycle-exact delays, so Wi-Fi, USB, flash or logging cannot move an edge.
//!
//! The program (four instructions, loaded once and shared by the state machines):
//!
//! ```text
//!     pull block      ; a word: delay D in bits 0..27, pattern in bits 28..31
//!     out x, 28
//! hold:
//!     jmp x-- hold    ; D + 1 cycles
//!     out pins, 4     ; the pattern appears on the axis's four pins
//! ```
//!
//! A word takes exactly `D + 4` cycles from the previous pattern change when it is already
//! in the FIFO, so words are chained: each delay counts from the previous edge, and as
//! long as the FIFO never runs dry every edge lands on its scheduled microsecond. The
//! motion task queues events [`LOOKAHEAD_US`] ahead; while a move runs, the feeder also
//! pads the timeline with words that repeat the current pattern (no edge) up to the
//! time [`KNOWN_UNTIL_US`] before which every event is queued, so the state machine
//! is never idle mid-move and no step is timed from a FIFO refill. When an axis has
//! been idle, its next event (a move's coil power-on) starts a new timeline from the
//! time it is pushed, within a few microseconds; every later edge chains from it.
//!
//! The jitter bound between steps of a move is therefore zero (one 8 ns cycle of
//! rounding, carried over so it never accumulates) as long as the refill deadline is met:
//! the feeder runs on the high-priority executor, woken by the FIFO interrupt, and has
//! the lookahead (2 ms) against a worst-case wake-up latency of about 0.15 ms. A missed
//! deadline delays steps (never drops or reorders them) and is counted in [`LATE`].

use embassy_futures::select::{Either, select};
use embassy_rp::clocks::clk_sys_freq;
use embassy_rp::gpio::Level;
use embassy_rp::pio::program::pio_asm;
use embassy_rp::pio::{
    Common, Config, Direction, FifoJoin, Instance, LoadedProgram, Pin, ShiftConfig, ShiftDirection,
    StateMachine,
};
use embassy_time::{Instant, Timer};
use portable_atomic::{AtomicU32, Ordering};

use super::events::{Event, PULSE_US, Queue, SETUP_US, STEP};
use super::log::warn;
use super::motion::{ENGAGED, KNOWN_UNTIL_US, LOOKAHEAD_US};
use super::now_us;

/// Cycles a word costs beyond its delay field.
const WORD_CYCLES: u32 = 4;
/// The largest delay field (28 bits): 2.1 s at 125 MHz (RP2040), 1.8 s at 150 MHz (RP2350).
const MAX_DELAY: u32 = (1 << 28) - 1;
/// A timeline whose end is this close to now may be finishing: wait it out, then restart.
const GUARD_US: u64 = 10;
/// While a move runs, pad the timeline when it has less than this left.
const PAD_AHEAD_US: u64 = LOOKAHEAD_US / 4;
/// Longest padding word.
const PAD_US: u64 = LOOKAHEAD_US / 2;

/// Events that could not be played on time (should stay 0).
pub static LATE: AtomicU32 = AtomicU32::new(0);

/// The program, loaded once into the board's step PIO block.
pub struct StepProgram<'d, P: Instance> {
    program: LoadedProgram<'d, P>,
}

impl<'d, P: Instance> StepProgram<'d, P> {
    pub fn load(common: &mut Common<'d, P>) -> Self {
        let source = pio_asm!(
            ".wrap_target",
            "    pull block",
            "    out x, 28",
            "hold:",
            "    jmp x-- hold",
            "    out pins, 4",
            ".wrap",
        );
        Self {
            program: common.load_program(&source.program),
        }
    }
}

/// Plays one axis's queue on its state machine.
pub struct Feeder<'d, P: Instance, const SM: usize> {
    sm: StateMachine<'d, P, SM>,
    queue: &'static Queue,
    cycles_per_us: u32,
    /// When the last word scheduled changes the pins (µs since boot).
    end_us: u64,
    /// The pattern of the last word scheduled.
    pattern: u8,
    /// Cycles spent beyond what was asked (words cost at least [`WORD_CYCLES`]),
    /// taken off the next word.
    owed: u32,
    /// Earliest time to try padding again.
    next_pad_us: u64,
}

impl<'d, P: Instance, const SM: usize> Feeder<'d, P, SM> {
    /// Sets up the state machine on `pins` (four consecutive GPIOs, bit 0 first), all low.
    pub fn new(
        mut sm: StateMachine<'d, P, SM>,
        program: &StepProgram<'d, P>,
        pins: [Pin<'d, P>; 4],
        queue: &'static Queue,
    ) -> Self {
        let pins = [&pins[0], &pins[1], &pins[2], &pins[3]];
        sm.set_pins(Level::Low, &pins);
        sm.set_pin_dirs(Direction::Out, &pins);
        let mut config = Config::default();
        config.use_program(&program.program, &[]);
        config.set_out_pins(&pins);
        config.shift_out = ShiftConfig {
            threshold: 32,
            direction: ShiftDirection::Right,
            auto_fill: false,
        };
        // Both FIFOs as one 8-word transmit FIFO.
        config.fifo_join = FifoJoin::TxOnly;
        config.clock_divider = 1u8.into();
        sm.set_config(&config);
        sm.set_enable(true);
        Self {
            sm,
            queue,
            cycles_per_us: clk_sys_freq() / 1_000_000,
            end_us: 0,
            pattern: 0,
            owed: 0,
            next_pad_us: 0,
        }
    }

    /// Feeds the state machine forever.
    pub async fn run(mut self) -> ! {
        loop {
            let next = match self.pad_time() {
                Some(at) => {
                    let timer = Timer::at(Instant::from_micros(at));
                    match select(self.queue.receive(), timer).await {
                        Either::First(event) => Some(event),
                        Either::Second(()) => None,
                    }
                }
                None => Some(self.queue.receive().await),
            };
            match next {
                Some(event) => self.play(event).await,
                None => self.pad().await,
            }
        }
    }

    /// When to pad the timeline next: only while a move runs and the timeline is live.
    fn pad_time(&self) -> Option<u64> {
        let live = self.end_us > now_us().saturating_add(GUARD_US);
        (live && ENGAGED.load(Ordering::Acquire)).then(|| {
            self.end_us
                .saturating_sub(PAD_AHEAD_US)
                .max(self.next_pad_us)
        })
    }

    async fn pad(&mut self) {
        let known = KNOWN_UNTIL_US.load(Ordering::Acquire);
        let until = known.min(self.end_us.saturating_add(PAD_US));
        if until > self.end_us {
            self.schedule(until, self.pattern).await;
        } else {
            // The motion task is behind: look again shortly.
            self.next_pad_us = now_us().saturating_add(GUARD_US);
        }
    }

    async fn play(&mut self, event: Event) {
        if event.pulse {
            let rest = event.pattern & !STEP;
            if rest != self.pattern {
                self.schedule(event.at_us.saturating_sub(SETUP_US), rest)
                    .await;
            }
            self.schedule(event.at_us, event.pattern).await;
            self.schedule(event.at_us.saturating_add(PULSE_US), rest)
                .await;
        } else {
            self.schedule(event.at_us, event.pattern).await;
        }
    }

    /// Queues `pattern` to appear at `at_us`.
    async fn schedule(&mut self, at_us: u64, pattern: u8) {
        let mut now = now_us();
        let start = if self.end_us > now.saturating_add(GUARD_US) {
            // Still busy: chain on the previous edge.
            self.end_us
        } else {
            // Idle, or finishing: start a new timeline once it certainly has finished.
            while now <= self.end_us.saturating_add(GUARD_US) {
                now = now_us();
            }
            self.owed = 0;
            now
        };
        if at_us < start {
            LATE.fetch_add(1, Ordering::Relaxed);
            warn!("axis step late by {} us", start - at_us);
        }
        let due = at_us.max(start);
        let mut cycles = (due - start).saturating_mul(u64::from(self.cycles_per_us));
        // Long gaps: words repeating the current pattern first.
        const LONGEST: u32 = MAX_DELAY + WORD_CYCLES;
        while cycles > u64::from(LONGEST) {
            self.push(LONGEST, self.pattern).await;
            cycles -= u64::from(LONGEST);
        }
        // Fits: at most LONGEST.
        self.push(u32::try_from(cycles).unwrap_or(LONGEST), pattern)
            .await;
        self.end_us = due;
        self.pattern = pattern;
    }

    /// Pushes one word that takes `cycles` (at least [`WORD_CYCLES`], the excess owed).
    async fn push(&mut self, cycles: u32, pattern: u8) {
        let wanted = cycles.saturating_sub(self.owed);
        self.owed = self.owed.saturating_sub(cycles);
        let delay = wanted.max(WORD_CYCLES) - WORD_CYCLES;
        self.owed += WORD_CYCLES.saturating_sub(wanted);
        let word = delay | (u32::from(pattern & 0xF) << 28);
        self.sm.tx().wait_push(word).await;
    }
}
