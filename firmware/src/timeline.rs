//! An axis's pin changes as the words of a cycle-counting step engine.
//!
//! Each word holds a delay and the pin pattern that appears once it has run out, counted
//! from the previous change, so a chain of words reproduces the planned times to the clock
//! cycle however late the words are handed over, as long as the engine never runs out of
//! them. The board's PIO program (`board/pio_steps.rs`) plays them:
//!
//! ```text
//!     pull block      ; a word: delay D in bits 0..27, pattern in bits 28..31
//!     out x, 28
//! hold:
//!     jmp x-- hold    ; D + 1 cycles
//!     out pins, 4     ; the pattern appears on the axis's four pins
//! ```
//!
//! A word already waiting takes exactly `D + WORD_CYCLES` cycles from the previous change.
//! [`Timeline`] turns timed changes into such words: a change due before the previous one
//! ends is late and chained right after it (counted, never dropped or reordered); cycles a
//! word costs beyond what was asked (the shortest takes [`WORD_CYCLES`]) are taken off the
//! next, so rounding never accumulates; gaps longer than one word holds are split.
//! [`Timeline::pad`] repeats the current pattern while later changes are not known yet, so
//! the engine is never left waiting for words in the middle of a move.
//!
//! Hardware independent: the board hands the words to its state machines; the tests here
//! play them back in cycles.

/// Cycles a word costs beyond its delay field.
pub const WORD_CYCLES: u32 = 4;

/// The largest delay field (28 bits): 2.1 s at 125 MHz (RP2040), 1.8 s at 150 MHz (RP2350).
pub const MAX_DELAY: u32 = (1 << 28) - 1;

/// A timeline ending this close to now may still be playing its last word.
pub const GUARD_US: u64 = 10;

/// The longest a single word lasts, in cycles.
const LONGEST: u32 = MAX_DELAY + WORD_CYCLES;

/// One axis's chain of words.
#[derive(Clone, Debug)]
pub struct Timeline {
    cycles_per_us: u32,
    /// When the last word queued changes the pins (µs of the board's clock).
    end_us: u64,
    /// The pattern of the last word queued.
    pattern: u8,
    /// Cycles spent beyond what was asked, taken off the next word.
    owed: u32,
}

impl Timeline {
    /// An idle timeline for an engine running `cycles_per_us` cycles per microsecond.
    pub const fn new(cycles_per_us: u32) -> Self {
        Self {
            cycles_per_us,
            end_us: 0,
            pattern: 0,
            owed: 0,
        }
    }

    /// Whether words are still being played at `now_us` (later changes chain on them).
    pub fn is_live(&self, now_us: u64) -> bool {
        self.end_us > now_us.saturating_add(GUARD_US)
    }

    /// When the last word has certainly been played: a new timeline starts after that.
    pub fn settles_at_us(&self) -> u64 {
        self.end_us.saturating_add(GUARD_US)
    }

    /// When the last word queued changes the pins.
    pub fn end_us(&self) -> u64 {
        self.end_us
    }

    /// The pins once every word queued has been played.
    pub fn pattern(&self) -> u8 {
        self.pattern
    }

    /// Queues `pattern` to appear at `at_us`, handing the words to `word`. On a live
    /// timeline the change is chained on the previous one; otherwise a new timeline starts
    /// at `now_us`, which must be past [`Self::settles_at_us`] and as close as can be to
    /// when the engine receives the first word. Returns how late the change is, in µs (0
    /// when on time).
    pub fn change(
        &mut self,
        at_us: u64,
        pattern: u8,
        now_us: u64,
        word: &mut impl FnMut(u32),
    ) -> u64 {
        let start = if self.is_live(now_us) {
            self.end_us
        } else {
            self.owed = 0;
            now_us
        };
        let due = at_us.max(start);
        self.hold(due - start, pattern, word);
        self.end_us = due;
        self.pattern = pattern;
        start.saturating_sub(at_us)
    }

    /// Repeats the current pattern until `until_us` on a live timeline, so the engine does
    /// not wait for words before then; nothing when the timeline is idle at `now_us` or
    /// already reaches that far.
    pub fn pad(&mut self, until_us: u64, now_us: u64, word: &mut impl FnMut(u32)) {
        if self.is_live(now_us) && until_us > self.end_us {
            self.hold(until_us - self.end_us, self.pattern, word);
            self.end_us = until_us;
        }
    }

    /// Words lasting `us` in all, the last one changing the pins to `pattern`.
    fn hold(&mut self, us: u64, pattern: u8, word: &mut impl FnMut(u32)) {
        let mut cycles = us.saturating_mul(u64::from(self.cycles_per_us));
        while cycles > u64::from(LONGEST) {
            self.push(LONGEST, self.pattern, word);
            cycles -= u64::from(LONGEST);
        }
        self.push(u32::try_from(cycles).unwrap_or(LONGEST), pattern, word);
    }

    /// One word that takes `cycles` (at least [`WORD_CYCLES`]; the excess is owed).
    fn push(&mut self, cycles: u32, pattern: u8, word: &mut impl FnMut(u32)) {
        let wanted = cycles.saturating_sub(self.owed);
        self.owed = self.owed.saturating_sub(cycles) + WORD_CYCLES.saturating_sub(wanted);
        let delay = wanted.max(WORD_CYCLES) - WORD_CYCLES;
        word(delay | (u32::from(pattern & 0xF) << 28));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MHZ: u32 = 125;

    /// Plays words back to back from cycle `start`: the cycle and pattern of each change.
    fn play(words: &[u32], start: u64) -> Vec<(u64, u8)> {
        let mut at = start;
        words
            .iter()
            .map(|&w| {
                at += u64::from(w & MAX_DELAY) + u64::from(WORD_CYCLES);
                (at, (w >> 28) as u8)
            })
            .collect()
    }

    #[test]
    fn chained_changes_land_on_their_cycle() {
        let mut timeline = Timeline::new(MHZ);
        let mut words = Vec::new();
        // Queued ahead of time, as the board queues them (2 ms ahead).
        assert_eq!(timeline.change(1_000, 0b0001, 0, &mut |w| words.push(w)), 0);
        for (i, pattern) in [0b0011u8, 0b0010, 0b0110].into_iter().enumerate() {
            let at = 1_000 + 250 * (i as u64 + 1);
            assert_eq!(timeline.change(at, pattern, 0, &mut |w| words.push(w)), 0);
        }
        let played = play(&words, 0);
        assert_eq!(
            played,
            [
                (125_000, 0b0001),
                (156_250, 0b0011),
                (187_500, 0b0010),
                (218_750, 0b0110)
            ]
        );
        assert_eq!((timeline.end_us(), timeline.pattern()), (1_750, 6));
    }

    #[test]
    fn cycles_owed_by_short_words_are_paid_back_by_the_next() {
        let mut timeline = Timeline::new(MHZ);
        let mut words = Vec::new();
        timeline.change(1_000, 1, 0, &mut |w| words.push(w));
        // Two changes at the same microsecond: the second costs WORD_CYCLES it was not
        // given, and the change after them is still on its cycle.
        timeline.change(2_000, 2, 0, &mut |w| words.push(w));
        timeline.change(2_000, 3, 0, &mut |w| words.push(w));
        timeline.change(3_000, 4, 0, &mut |w| words.push(w));
        let played = play(&words, 0);
        assert_eq!(played[1].0, 2_000 * 125);
        assert_eq!(played[2].0 - played[1].0, u64::from(WORD_CYCLES));
        assert_eq!(played[3].0, 3_000 * 125);
    }

    #[test]
    fn a_late_change_is_chained_after_the_previous_and_reported() {
        let mut timeline = Timeline::new(MHZ);
        let mut words = Vec::new();
        timeline.change(100, 1, 0, &mut |w| words.push(w));
        timeline.change(500, 2, 0, &mut |w| words.push(w));
        assert_eq!(
            timeline.change(400, 3, 0, &mut |w| words.push(w)),
            100,
            "100 µs late"
        );
        assert_eq!(timeline.end_us(), 500);
        let played = play(&words, 0);
        assert_eq!(played[2].0 - played[1].0, u64::from(WORD_CYCLES));
        assert_eq!(timeline.change(600, 4, 0, &mut |w| words.push(w)), 0);
        let played = play(&words, 0);
        assert_eq!(
            played[3].0,
            600 * 125,
            "back on its cycle after the late one"
        );
    }

    #[test]
    fn an_idle_timeline_restarts_at_now_and_padding_keeps_a_live_one_going() {
        let mut timeline = Timeline::new(MHZ);
        let mut words = Vec::new();
        timeline.change(1_000, 1, 900, &mut |w| words.push(w));
        // Padding: the same pattern, no new change, up to the horizon.
        timeline.pad(3_000, 950, &mut |w| words.push(w));
        assert_eq!(timeline.end_us(), 3_000);
        assert_eq!((words.len(), words[1] >> 28), (2, 1));
        // Idle: nothing is padded, and the next change starts from now.
        timeline.pad(9_000, 5_000, &mut |w| words.push(w));
        assert_eq!(words.len(), 2);
        assert!(!timeline.is_live(5_000));
        assert_eq!(
            timeline.change(4_000, 2, 5_000, &mut |w| words.push(w)),
            1_000
        );
        assert_eq!(words[2] & MAX_DELAY, 0, "at once, from the restart");
    }

    #[test]
    fn long_gaps_are_split_into_words_that_keep_the_pattern() {
        let mut timeline = Timeline::new(MHZ);
        let mut words = Vec::new();
        timeline.change(0, 5, 0, &mut |w| words.push(w));
        let gap_us = 5_000_000;
        timeline.change(gap_us, 6, 0, &mut |w| words.push(w));
        let played = play(&words, 0);
        assert!(played.len() > 3, "{} words", played.len());
        assert!(played[1..played.len() - 1].iter().all(|c| c.1 == 5));
        let last = played.last().unwrap();
        assert_eq!((last.0 - played[0].0, last.1), (gap_us * 125, 6));
    }
}
