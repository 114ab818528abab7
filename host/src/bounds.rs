//! Bounds on numbers that come from files, flags and the network: each is checked where it
//! is parsed, and refused with the field's name and the range it must lie in, so nothing
//! downstream (a `Duration`, an allocation, a thread count) can overflow or panic on it.

use std::time::Duration;

/// The longest wait any setting may ask for: a day. Longer settle times or timeouts are
/// typing mistakes, and `Duration` arithmetic on them would overflow.
pub const LONGEST_WAIT_S: f64 = 86_400.0;

/// A time in seconds read from `field`: finite, at most [`LONGEST_WAIT_S`], and above zero
/// unless `zero_allowed`.
pub fn seconds(field: &str, value: f64, zero_allowed: bool) -> Result<Duration, String> {
    let low_ok = if zero_allowed {
        value >= 0.0
    } else {
        value > 0.0
    };
    if !(value.is_finite() && low_ok && value <= LONGEST_WAIT_S) {
        let low = if zero_allowed { ">= 0 s" } else { "> 0 s" };
        return Err(format!(
            "{field}: must be a time {low} and at most {LONGEST_WAIT_S} s (a day), got {value:?}"
        ));
    }
    Duration::try_from_secs_f64(value).map_err(|error| format!("{field}: {error}"))
}

/// A number read from `field` that must lie in `low..=high` (`unit` names what it counts).
pub fn number_in(field: &str, value: f64, low: f64, high: f64, unit: &str) -> Result<f64, String> {
    if value.is_finite() && (low..=high).contains(&value) {
        Ok(value)
    } else {
        Err(format!(
            "{field}: must be from {low} to {high} {unit}, got {value:?}"
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seconds_are_bounded_on_both_sides() {
        assert_eq!(seconds("t", 0.5, false), Ok(Duration::from_millis(500)));
        assert_eq!(seconds("t", 0.0, true), Ok(Duration::ZERO));
        for bad in [0.0, -1.0, 1e20, 1e308, f64::NAN, f64::INFINITY] {
            let error = seconds("camera.timeout_s", bad, false).unwrap_err();
            assert!(
                error.starts_with("camera.timeout_s: must be a time > 0 s"),
                "{error}"
            );
        }
        assert!(seconds("s", -0.1, true).unwrap_err().contains(">= 0 s"));
        assert!(seconds("s", LONGEST_WAIT_S, true).is_ok());
    }

    #[test]
    fn numbers_name_their_field_and_range() {
        assert_eq!(number_in("x", 2.0, 1.0, 3.0, "times"), Ok(2.0));
        let error = number_in("--time-scale", 1e-300, 1e-3, 1e6, "times real time").unwrap_err();
        assert_eq!(
            error,
            "--time-scale: must be from 0.001 to 1000000 times real time, got 1e-300"
        );
        assert!(number_in("x", f64::NAN, 0.0, 1.0, "").is_err());
    }
}
