//! Step timing by PIO fed by DMA: one state machine per axis plays the axis's pin changes
//! with cycle-exact delays, and two DMA channels per axis feed it from a RAM ring, so no
//! CPU work (Wi-Fi, USB, the link's cryptography, a critical section, a flash stall) stands
//! between a word and the state machine that needs it.
//!
//! The program and its words are the core's ([`crate::timeline`]): each word holds the
//! delay from the previous change and the pattern that appears then, so as long as the
//! state machine never runs out of words, every edge lands on its planned cycle.
//!
//! The motion task is the only producer ([`StepEngine`] lives in its
//! [`EventSink`](super::events::EventSink)): it writes each axis's words into the axis's
//! ring [`LOOKAHEAD_US`](super::motion::LOOKAHEAD_US) ahead of their time and
//! hands them to the DMA at the end of every round ([`StepEngine::commit`]). While a move
//! runs it pads every live timeline up to the time before which every change is known, so
//! the state machine never waits for words mid-move; the one deadline left on the CPU is
//! the motion task's own: to run again before what it handed over has been played (2 ms
//! ahead, woken every 1 ms).
//!
//! The DMA hand-over never replays stale words: each axis has two channels that take turns,
//! each carrying one run of consecutive words ("chunk"), the running one chained to the
//! other only once that one holds fresh words. A chunk still waiting for its turn is
//! lengthened instead, with the chain held open meanwhile. When the producer is late the
//! DMA stops at the last word handed over, the state machine stalls on its empty FIFO,
//! and the steps that follow are late, never lost nor reordered.
//!
//! Underruns are read from the hardware: the PIO's sticky TXSTALL flag (FDEBUG) says a
//! state machine found its FIFO empty. Checked at the start of every round, a stall while
//! the axis's timeline was padded through the previous round (the producer promised
//! continuity) is an underrun, counted per axis ([`StepEngine::check`]) and reported in
//! `Status`; a stall after a timeline's last change is an axis at rest.

use core::sync::atomic::{Ordering, compiler_fence};

use embassy_rp::Peri;
use embassy_rp::clocks::clk_sys_freq;
use embassy_rp::dma::ChannelInstance;
use embassy_rp::gpio::Level;
use embassy_rp::pac;
use embassy_rp::pac::dma::regs::CtrlTrig;
use embassy_rp::pac::dma::vals::{DataSize, TreqSel};
use embassy_rp::pio::program::pio_asm;
use embassy_rp::pio::{
    Common, Config, Direction, FifoJoin, LoadedProgram, Pin, ShiftConfig, ShiftDirection,
    StateMachine,
};
use static_cell::ConstStaticCell;

use super::events::{DROPPED, Event, PULSE_US, SETUP_US, STEP};
use super::log::warn;
use super::this::StepPio;
use super::{AXES, now_us};
use crate::timeline::Timeline;

/// Words in each axis's ring: a power of two, at least twice what the lookahead can hold
/// at the fastest rate (20,000 steps/s on STEP/DIR, two words a step: 80 in 2 ms).
const RING: u32 = 256;
/// log2 of the ring's size in bytes, for the DMA's address wrap.
const RING_BITS: u8 = 10;
const _: () = assert!(RING * 4 == 1 << RING_BITS);

/// Stall-flag reads after a new timeline's first word, waiting for the state machine to
/// take it (it does within a few cycles of the DMA's write).
const SETTLE_READS: usize = 64;

/// One axis's ring, aligned to its size for the DMA's address wrap.
#[repr(C, align(1024))]
pub struct Ring([u32; RING as usize]);

impl Ring {
    pub const fn new() -> Self {
        Self([0; RING as usize])
    }
}

impl Default for Ring {
    fn default() -> Self {
        Self::new()
    }
}

/// The rings of all axes.
type Rings = [Ring; AXES as usize];

/// The rings, handed to the engine once.
static RINGS: ConstStaticCell<Rings> = ConstStaticCell::new([const { Ring::new() }; AXES as usize]);

/// The state machines, one per axis, on the board's step PIO block.
pub struct Lanes {
    pub sm0: StateMachine<'static, StepPio, 0>,
    pub sm1: StateMachine<'static, StepPio, 1>,
    pub sm2: StateMachine<'static, StepPio, 2>,
    pub sm3: StateMachine<'static, StepPio, 3>,
}

/// What the engine needs of a running state machine.
trait Lane {
    /// Whether it stalled on an empty FIFO since the last call (the flag is cleared).
    fn stalled(&mut self) -> bool;
}

impl<const SM: usize> Lane for StateMachine<'static, StepPio, SM> {
    fn stalled(&mut self) -> bool {
        self.tx().stalled()
    }
}

impl Lanes {
    fn lane(&mut self, axis: usize) -> Option<&mut dyn Lane> {
        match axis {
            0 => Some(&mut self.sm0),
            1 => Some(&mut self.sm1),
            2 => Some(&mut self.sm2),
            3 => Some(&mut self.sm3),
            _ => None,
        }
    }
}

/// Two DMA channels for each axis, taken from their peripherals.
pub type Channels = [[u8; 2]; AXES as usize];

/// A DMA channel's number, the peripheral taken so nothing else uses it.
pub fn channel<T: ChannelInstance>(_: Peri<'static, T>) -> u8 {
    T::number()
}

/// The pins of all axes: four consecutive GPIOs each, bit 0 first.
pub type AxisPins = [[Pin<'static, StepPio>; 4]; AXES as usize];

/// The run of words a channel was last given.
#[derive(Clone, Copy)]
struct Chunk {
    /// Which of the axis's two channels.
    channel: usize,
    /// Its first word, as a running count of words written.
    start: u32,
    len: u32,
}

/// One axis's ring and its two DMA channels.
struct Feed {
    ring: &'static mut Ring,
    channels: [u8; 2],
    /// The channel configuration, less its chain target.
    control: CtrlTrig,
    /// Words written into the ring (a running count; the slot is this modulo [`RING`]).
    written: u32,
    /// Words handed to the DMA.
    committed: u32,
    /// The latest chunk handed over.
    latest: Option<Chunk>,
}

impl Feed {
    fn new(ring: &'static mut Ring, channels: [u8; 2], treq: TreqSel, fifo: *mut u32) -> Self {
        let mut control = CtrlTrig(0);
        control.set_en(true);
        control.set_data_size(DataSize::SIZE_WORD);
        control.set_incr_read(true);
        control.set_incr_write(false);
        control.set_ring_sel(false);
        control.set_ring_size(RING_BITS);
        control.set_treq_sel(treq);
        control.set_irq_quiet(true);
        let feed = Self {
            ring,
            channels,
            control,
            written: 0,
            committed: 0,
            latest: None,
        };
        for channel in channels {
            let regs = regs(channel);
            regs.write_addr().write_value(fifo as u32);
            regs.al1_ctrl().write_value(feed.control_chained(channel).0);
        }
        feed
    }

    /// The channel configuration with `chain_to` (itself: no chaining).
    fn control_chained(&self, chain_to: u8) -> CtrlTrig {
        let mut control = self.control;
        control.set_chain_to(chain_to);
        control
    }

    /// The bus address of word `index` (a running count).
    fn address(&self, index: u32) -> u32 {
        (self.ring.0.as_ptr() as u32).wrapping_add((index % RING) * 4)
    }

    /// Words the DMA has not read yet, at most (written or handed over).
    fn unread(&self) -> u32 {
        let waiting = self.written - self.committed;
        let Some(chunk) = self.latest else {
            return waiting;
        };
        let latest = self.channels[chunk.channel];
        let other = self.channels[1 - chunk.channel];
        let in_flight = if self.untriggered(chunk) {
            chunk.len + remaining(other)
        } else {
            // Plus one a channel may have read and not counted yet.
            remaining(latest) + 1
        };
        waiting + in_flight.min(RING)
    }

    /// Writes one word into the ring; `false` when the ring is full (never, at the rates
    /// the core allows).
    fn write(&mut self, word: u32) -> bool {
        if self.unread() >= RING - 1 {
            return false;
        }
        // The DMA has read this slot already (`unread`): it is ours to write.
        let Some(slot) = self.ring.0.get_mut((self.written % RING) as usize) else {
            return false;
        };
        *slot = word;
        self.written = self.written.wrapping_add(1);
        true
    }

    /// Whether `chunk`'s channel has not started on it yet.
    fn untriggered(&self, chunk: Chunk) -> bool {
        let channel = self.channels[chunk.channel];
        !busy(channel) && regs(channel).read_addr().read() == self.address(chunk.start)
    }

    /// Hands every word written so far to the DMA.
    fn commit(&mut self) {
        let len = self.written.wrapping_sub(self.committed);
        if len == 0 {
            return;
        }
        // The words are in RAM before any channel is told to read them.
        compiler_fence(Ordering::SeqCst);
        if let Some(chunk) = self.latest
            && self.untriggered(chunk)
        {
            let [channel, other] = [chunk.channel, 1 - chunk.channel].map(|c| self.channels[c]);
            // Hold the chain open, so the waiting chunk cannot start while it grows.
            regs(other)
                .al1_ctrl()
                .write_value(self.control_chained(other).0);
            if self.untriggered(chunk) {
                set_count(channel, chunk.len + len);
                regs(other)
                    .al1_ctrl()
                    .write_value(self.control_chained(channel).0);
                if !busy(other) && self.untriggered(chunk) {
                    trigger(channel);
                }
                self.latest = Some(Chunk {
                    len: chunk.len + len,
                    ..chunk
                });
                self.committed = self.written;
                return;
            }
            // It started just before the chain was held: the other channel is free.
        }
        let next = self.latest.map_or(0, |chunk| 1 - chunk.channel);
        let channel = self.channels[next];
        let regs_next = regs(channel);
        regs_next
            .read_addr()
            .write_value(self.address(self.committed));
        set_count(channel, len);
        regs_next
            .al1_ctrl()
            .write_value(self.control_chained(channel).0);
        let chunk = Chunk {
            channel: next,
            start: self.committed,
            len,
        };
        match self.latest {
            Some(previous) => {
                let running = self.channels[previous.channel];
                regs(running)
                    .al1_ctrl()
                    .write_value(self.control_chained(channel).0);
                // Finished before the chain was set: start the new chunk here.
                if !busy(running) && self.untriggered(chunk) {
                    trigger(channel);
                }
            }
            None => trigger(channel),
        }
        self.latest = Some(chunk);
        self.committed = self.written;
    }
}

fn regs(channel: u8) -> pac::dma::Channel {
    pac::DMA.ch(usize::from(channel))
}

fn busy(channel: u8) -> bool {
    regs(channel).ctrl_trig().read().busy()
}

fn trigger(channel: u8) {
    pac::DMA
        .multi_chan_trigger()
        .write(|w| w.set_multi_chan_trigger(1 << channel));
}

/// Transfers `channel` has left in its current run.
fn remaining(channel: u8) -> u32 {
    if !busy(channel) {
        return 0;
    }
    #[cfg(feature = "rp2040")]
    return regs(channel).trans_count().read();
    #[cfg(feature = "rp235x")]
    return regs(channel).trans_count().read().count();
}

/// Sets the length of `channel`'s next run (it takes it when triggered).
fn set_count(channel: u8, count: u32) {
    #[cfg(feature = "rp2040")]
    regs(channel).trans_count().write_value(count);
    #[cfg(feature = "rp235x")]
    regs(channel).trans_count().write(|w| {
        w.set_mode(pac::dma::vals::TransCountMode::NORMAL);
        w.set_count(count);
    });
}

/// One axis: its words' timeline, its feed, and what is known of its stalls.
struct Axis {
    timeline: Timeline,
    feed: Feed,
    /// Padded through the last round: a stall before the next one is an underrun.
    open: bool,
    underruns: u32,
}

/// The state machines, their rings and DMA channels, and every axis's timeline.
pub struct StepEngine {
    /// Keeps the program loaded.
    _common: Common<'static, StepPio>,
    lanes: Lanes,
    axes: [Axis; AXES as usize],
}

impl StepEngine {
    /// Loads the program, sets up one state machine per axis on `pins` (all low) fed by the
    /// axis's two `channels` from its ring, and starts them. Once: there is one set of
    /// rings (use [`crate::step_engine`]).
    pub fn new(
        mut common: Common<'static, StepPio>,
        mut lanes: Lanes,
        pins: AxisPins,
        channels: Channels,
    ) -> Option<Self> {
        let rings = RINGS.try_take()?;
        let source = pio_asm!(
            ".wrap_target",
            "    pull block",
            "    out x, 28",
            "hold:",
            "    jmp x-- hold",
            "    out pins, 4",
            ".wrap",
        );
        let program = common.load_program(&source.program);
        let [p0, p1, p2, p3] = pins;
        let [c0, c1, c2, c3] = channels;
        let [r0, r1, r2, r3] = rings;
        let cycles_per_us = clk_sys_freq() / 1_000_000;
        let axis = |ring, channels, (treq, fifo)| Axis {
            timeline: Timeline::new(cycles_per_us),
            feed: Feed::new(ring, channels, treq, fifo),
            open: false,
            underruns: 0,
        };
        let axes = [
            axis(r0, c0, configure(&mut lanes.sm0, &program, &p0)),
            axis(r1, c1, configure(&mut lanes.sm1, &program, &p1)),
            axis(r2, c2, configure(&mut lanes.sm2, &program, &p2)),
            axis(r3, c3, configure(&mut lanes.sm3, &program, &p3)),
        ];
        Some(Self {
            _common: common,
            lanes,
            axes,
        })
    }

    /// Counts the underruns since the last round (see the module documentation); every
    /// axis's count since start-up.
    pub fn check(&mut self) -> [u32; AXES as usize] {
        let mut counts = [0; AXES as usize];
        for (index, axis) in self.axes.iter_mut().enumerate() {
            let stalled = self.lanes.lane(index).is_some_and(|lane| lane.stalled());
            if stalled && axis.open {
                axis.underruns = axis.underruns.saturating_add(1);
                warn!("axis {}: step engine ran out of words", index);
            }
            counts[index] = axis.underruns;
        }
        counts
    }

    /// Queues `event` on `axis`'s timeline.
    pub fn play(&mut self, axis: u8, event: Event) {
        if event.pulse {
            let rest = event.pattern & !STEP;
            if let Some(state) = self.axes.get(usize::from(axis))
                && rest != state.timeline.pattern()
            {
                self.change(axis, event.at_us.saturating_sub(SETUP_US), rest);
            }
            self.change(axis, event.at_us, event.pattern);
            self.change(axis, event.at_us.saturating_add(PULSE_US), rest);
        } else {
            self.change(axis, event.at_us, event.pattern);
        }
    }

    /// Pads the live timelines up to `known_until_us` when `engaged` (a move runs), and
    /// hands every word written to the DMA.
    pub fn commit(&mut self, known_until_us: u64, engaged: bool) {
        let now = now_us();
        for axis in self.axes.iter_mut() {
            let Axis { timeline, feed, .. } = axis;
            axis.open = engaged && timeline.is_live(now);
            if axis.open {
                timeline.pad(known_until_us, now, &mut |word| write(feed, word));
            }
            feed.commit();
        }
    }

    fn change(&mut self, axis: u8, at_us: u64, pattern: u8) {
        let index = usize::from(axis);
        let Some(Axis { timeline, feed, .. }) = self.axes.get_mut(index) else {
            return;
        };
        let mut now = now_us();
        let restart = !timeline.is_live(now);
        if restart {
            // The last word may still be playing: start anew once it certainly has.
            while now <= timeline.settles_at_us() {
                now = now_us();
            }
            // What was queued before is handed over first: the restart counts from now.
            feed.commit();
        }
        let late = timeline.change(at_us, pattern, now, &mut |word| write(feed, word));
        if late > 0 {
            warn!("axis {}: pin change late by {} us", axis, late);
        }
        if restart {
            feed.commit();
            // The state machine was waiting for this word: clear the stall it left.
            if let Some(lane) = self.lanes.lane(index) {
                for _ in 0..SETTLE_READS {
                    if !lane.stalled() {
                        break;
                    }
                }
            }
        }
    }
}

/// Writes `word` into `feed`'s ring, counting it dropped when the ring is full.
fn write(feed: &mut Feed, word: u32) {
    if !feed.write(word) {
        DROPPED.fetch_add(1, portable_atomic::Ordering::Relaxed);
        warn!("step ring full: word dropped");
    }
}

/// The step engine on PIO block `$pio` (the board's `StepPio`; `$irqs` binds its
/// interrupt), the Pico header's GP2-GP17 (four per axis) and DMA channels 1-8 (the
/// radio's driver keeps channel 0), taken out of `$p`, the `embassy_rp::Peripherals`.
/// `None` when an engine was made already.
#[macro_export]
macro_rules! step_engine {
    ($p:ident, $pio:expr, $irqs:expr) => {{
        use $crate::board::pio_steps::{Lanes, StepEngine, channel};
        let embassy_rp::pio::Pio {
            mut common,
            sm0,
            sm1,
            sm2,
            sm3,
            ..
        } = embassy_rp::pio::Pio::new($pio, $irqs);
        let pins = [
            [
                common.make_pio_pin($p.PIN_2),
                common.make_pio_pin($p.PIN_3),
                common.make_pio_pin($p.PIN_4),
                common.make_pio_pin($p.PIN_5),
            ],
            [
                common.make_pio_pin($p.PIN_6),
                common.make_pio_pin($p.PIN_7),
                common.make_pio_pin($p.PIN_8),
                common.make_pio_pin($p.PIN_9),
            ],
            [
                common.make_pio_pin($p.PIN_10),
                common.make_pio_pin($p.PIN_11),
                common.make_pio_pin($p.PIN_12),
                common.make_pio_pin($p.PIN_13),
            ],
            [
                common.make_pio_pin($p.PIN_14),
                common.make_pio_pin($p.PIN_15),
                common.make_pio_pin($p.PIN_16),
                common.make_pio_pin($p.PIN_17),
            ],
        ];
        let channels = [
            [channel($p.DMA_CH1), channel($p.DMA_CH2)],
            [channel($p.DMA_CH3), channel($p.DMA_CH4)],
            [channel($p.DMA_CH5), channel($p.DMA_CH6)],
            [channel($p.DMA_CH7), channel($p.DMA_CH8)],
        ];
        let lanes = Lanes { sm0, sm1, sm2, sm3 };
        StepEngine::new(common, lanes, pins, channels)
    }};
}

/// Sets up `sm` on `pins`, all low, and starts it; its DMA request line and FIFO address.
fn configure<const SM: usize>(
    sm: &mut StateMachine<'static, StepPio, SM>,
    program: &LoadedProgram<'static, StepPio>,
    pins: &[Pin<'static, StepPio>; 4],
) -> (TreqSel, *mut u32) {
    let pins = [&pins[0], &pins[1], &pins[2], &pins[3]];
    sm.set_pins(Level::Low, &pins);
    sm.set_pin_dirs(Direction::Out, &pins);
    let mut config = Config::default();
    config.use_program(program, &[]);
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
    (sm.tx_treq(), sm.tx_fifo_ptr())
}
