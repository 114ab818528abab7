//! Logging: defmt over RTT in the board image; compiled out of the emulator image.

#[cfg(feature = "board")]
pub(crate) use defmt::{info, warn};

/// Evaluates nothing but borrows the arguments, so they count as used.
#[cfg(not(feature = "board"))]
macro_rules! discard {
    ($format:literal $(, $argument:expr)* $(,)?) => {{
        $(let _ = &$argument;)*
    }};
}

#[cfg(not(feature = "board"))]
pub(crate) use {discard as info, discard as warn};
