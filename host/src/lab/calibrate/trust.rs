//! Whether a calibration can be trusted: a fit is refused, with the reasons, when the
//! tracked beam did not move with the commands, when the residual is large against the
//! detector's uncertainty of a beam centre, or when the fit cannot tell what it measured
//! (ill-conditioned). Every reason says what was measured and what was needed.

use super::fit::{AffineFit, BacklashFit};

/// A beam must travel at least this far over a scan for its response to be measured, px...
pub const MIN_TRAVEL_PX: f64 = 5.0;
/// ... and this many times the detector's centre uncertainty.
pub const TRAVEL_NOISES: f64 = 10.0;
/// A residual above this many detector uncertainties is suspect ...
pub const RESIDUAL_NOISES: f64 = 5.0;
/// ... unless it is below this floor (the mount's and the beam shape's own departures from
/// a straight line), px ...
pub const RESIDUAL_FLOOR_PX: f64 = 1.0;
/// ... or below this share of the beam's travel over the scan.
pub const RESIDUAL_SHARE_OF_TRAVEL: f64 = 0.01;
/// A response column must be this many times the length a column of pure noise would have.
pub const RESPONSE_SIGNIFICANCE: f64 = 10.0;
/// Axes that move the beam along nearly one line: larger singular value over the smaller.
pub const MAX_CONDITION_NUMBER: f64 = 10.0;
/// A backlash whose uncertainty is more than this share of the loop's amplitude is not known.
pub const MAX_BACKLASH_UNCERTAINTY_SHARE: f64 = 0.25;

/// The median of the detector's centre uncertainties of the beams a fit used, px.
pub fn detector_sigma(uncertainties: &[f64]) -> f64 {
    let mut sorted: Vec<f64> = uncertainties
        .iter()
        .copied()
        .filter(|u| u.is_finite())
        .collect();
    if sorted.is_empty() {
        return 0.0;
    }
    sorted.sort_by(f64::total_cmp);
    sorted[sorted.len() / 2]
}

fn travel_needed(sigma_px: f64) -> f64 {
    MIN_TRAVEL_PX.max(TRAVEL_NOISES * sigma_px)
}

fn residual_limit(sigma_px: f64, travel_px: f64) -> f64 {
    (RESIDUAL_NOISES * sigma_px)
        .max(RESIDUAL_FLOOR_PX)
        .max(RESIDUAL_SHARE_OF_TRAVEL * travel_px)
}

/// Why a mirror's response fit is not to be trusted (empty: trusted). `axes` names the two
/// axes, `span` is the scan's half-width in steps, `sigma_px` the detector's uncertainty.
pub fn response_doubts(fit: &AffineFit, axes: [&str; 2], span: f64, sigma_px: f64) -> Vec<String> {
    let mut doubts = Vec::new();
    if fit.points < 4 {
        doubts.push(format!(
            "only {} images showed the beam; at least 4 are needed to check the fit (use a larger --grid or a smaller --span)",
            fit.points
        ));
    }
    let travel = [0, 1].map(|k| fit.matrix[0][k].hypot(fit.matrix[1][k]) * 2.0 * span);
    let needed = travel_needed(sigma_px);
    for (k, name) in axes.iter().enumerate() {
        if travel[k] < needed {
            doubts.push(format!(
                "the tracked beam did not move with {name}: {:.2} px over {:.0} steps, where at least {needed:.1} px is needed (check the wiring and the rig file's [axes] map, or use a larger --span)",
                travel[k],
                2.0 * span
            ));
        }
    }
    let limit = residual_limit(sigma_px, travel[0].max(travel[1]));
    if fit.residual_rms > limit {
        doubts.push(format!(
            "the residual {:.2} px RMS is above {limit:.2} px (the detector's centre uncertainty is {sigma_px:.3} px): the beam tracked was not one beam moving linearly; move the other beams out of view, or use a smaller --span",
            fit.residual_rms
        ));
    }
    let noise = fit.residual_rms.max(sigma_px);
    let standard_error = fit.column_standard_error(noise);
    for (k, name) in axes.iter().enumerate() {
        let length = fit.matrix[0][k].hypot(fit.matrix[1][k]);
        if length < RESPONSE_SIGNIFICANCE * standard_error[k] && travel[k] >= needed {
            doubts.push(format!(
                "the fit cannot tell {name}'s response ({length:.4} px/step) from its noise ({:.4} px/step)",
                standard_error[k]
            ));
        }
    }
    let condition = fit.condition_number();
    if condition > MAX_CONDITION_NUMBER && travel.iter().all(|t| *t >= needed) {
        doubts.push(format!(
            "the two axes move the beam along nearly one line (condition number {condition:.1}, at most {MAX_CONDITION_NUMBER} is usable): the fit is ill-conditioned; check that the axes are the mirror's two tilts"
        ));
    }
    doubts
}

/// Why an axis's backlash fit is not to be trusted (empty: trusted).
pub fn backlash_doubts(
    fit: &BacklashFit,
    axis: &str,
    amplitude: f64,
    step: f64,
    sigma_px: f64,
) -> Vec<String> {
    let mut doubts = Vec::new();
    let travel = fit.gain.abs() * 2.0 * amplitude;
    let needed = travel_needed(sigma_px);
    if travel < needed {
        doubts.push(format!(
            "the tracked beam did not move with {axis}: {travel:.2} px over {:.0} steps ({:.2e} px/step), where at least {needed:.1} px is needed (check the wiring and the rig file's [axes] map)",
            2.0 * amplitude,
            fit.gain
        ));
        return doubts;
    }
    let limit = residual_limit(sigma_px, travel);
    if fit.residual_rms > limit {
        doubts.push(format!(
            "the residual {:.2} px RMS is above {limit:.2} px (the detector's centre uncertainty is {sigma_px:.3} px): the beam's motion is not a linear response through a dead band; move other beams out of view, or use a smaller --amplitude",
            fit.residual_rms
        ));
    }
    if fit.backlash + step >= amplitude {
        doubts.push(format!(
            "the fitted dead band ({:.0} steps) fills the loop of ±{amplitude:.0} steps: use a larger --amplitude",
            fit.backlash
        ));
    } else if fit.uncertainty > MAX_BACKLASH_UNCERTAINTY_SHARE * amplitude {
        doubts.push(format!(
            "the fit cannot tell the dead band better than ±{:.1} steps in a loop of ±{amplitude:.0} (ill-conditioned): use a smaller --step or a larger --amplitude",
            fit.uncertainty
        ));
    }
    doubts
}

#[cfg(test)]
mod tests {
    use super::super::fit::fit_affine;
    use super::*;

    fn grid() -> Vec<[f64; 2]> {
        [-1000.0, 0.0, 1000.0]
            .iter()
            .flat_map(|&a| [-1000.0, 0.0, 1000.0].map(|b| [a, b]))
            .collect()
    }

    fn fitted(map: impl Fn([f64; 2], usize) -> [f64; 2]) -> AffineFit {
        let steps = grid();
        let positions: Vec<[f64; 2]> = steps.iter().enumerate().map(|(i, &s)| map(s, i)).collect();
        fit_affine(&steps, &positions).unwrap()
    }

    /// A little deterministic noise, ±0.1 px.
    fn jitter(i: usize) -> f64 {
        ((i * 7919) % 11) as f64 / 50.0 - 0.1
    }

    #[test]
    fn a_clean_response_is_trusted() {
        let fit = fitted(|s, i| {
            [
                300.0 + 0.17 * s[0] + 0.01 * s[1] + jitter(i),
                200.0 - 0.01 * s[0] + 0.16 * s[1] - jitter(i + 3),
            ]
        });
        assert_eq!(
            response_doubts(&fit, ["a", "b"], 1000.0, 0.05),
            Vec::<String>::new()
        );
    }

    #[test]
    fn a_stationary_beam_is_refused_as_not_moving() {
        let fit = fitted(|_, i| [300.0 + jitter(i), 200.0 + jitter(i + 5)]);
        let doubts = response_doubts(&fit, ["a", "b"], 1000.0, 0.05);
        assert_eq!(doubts.len(), 2, "{doubts:?}");
        assert!(doubts[0].contains("did not move with a"), "{doubts:?}");
        assert!(doubts[1].contains("did not move with b"), "{doubts:?}");
    }

    #[test]
    fn an_unwired_second_axis_is_named() {
        let fit = fitted(|s, i| [300.0 + 0.17 * s[0] + jitter(i), 200.0 + jitter(i + 5)]);
        let doubts = response_doubts(&fit, ["m1a1", "m1a2"], 1000.0, 0.05);
        assert_eq!(doubts.len(), 1, "{doubts:?}");
        assert!(doubts[0].contains("did not move with m1a2"), "{doubts:?}");
    }

    #[test]
    fn jumping_between_beams_is_refused_by_its_residual() {
        // Half the points saw another beam 80 px away.
        let fit = fitted(|s, i| {
            let jump = if i % 2 == 0 { 80.0 } else { 0.0 };
            [300.0 + 0.17 * s[0] + jump, 200.0 + 0.16 * s[1]]
        });
        let doubts = response_doubts(&fit, ["a", "b"], 1000.0, 0.05);
        assert!(doubts.iter().any(|d| d.contains("residual")), "{doubts:?}");
    }

    #[test]
    fn axes_moving_the_beam_along_one_line_are_ill_conditioned() {
        let fit = fitted(|s, _| {
            [
                300.0 + 0.17 * s[0] + 0.16 * s[1],
                200.0 + 0.17 * s[0] + 0.15 * s[1],
            ]
        });
        let doubts = response_doubts(&fit, ["a", "b"], 1000.0, 0.05);
        assert!(
            doubts.iter().any(|d| d.contains("ill-conditioned")),
            "{doubts:?}"
        );
    }

    fn backlash(b: f64, gain: f64, uncertainty: f64, residual: f64) -> BacklashFit {
        BacklashFit {
            backlash: b,
            uncertainty,
            gain,
            offset: 0.0,
            residual_rms: residual,
        }
    }

    #[test]
    fn backlash_fits_are_refused_for_each_reason() {
        assert!(
            backlash_doubts(&backlash(40.0, 0.17, 1.0, 0.2), "x", 300.0, 10.0, 0.05).is_empty()
        );
        // The cavity case: the beam watched never moved.
        let doubts = backlash_doubts(&backlash(0.0, -0.0002, 14.0, 0.3), "x", 300.0, 10.0, 0.05);
        assert!(doubts[0].contains("did not move with x"), "{doubts:?}");
        let doubts = backlash_doubts(&backlash(40.0, 0.17, 1.0, 9.0), "x", 300.0, 10.0, 0.05);
        assert!(doubts[0].contains("residual"), "{doubts:?}");
        let doubts = backlash_doubts(&backlash(295.0, 0.17, 1.0, 0.2), "x", 300.0, 10.0, 0.05);
        assert!(doubts[0].contains("larger --amplitude"), "{doubts:?}");
        let doubts = backlash_doubts(&backlash(40.0, 0.17, 90.0, 0.2), "x", 300.0, 10.0, 0.05);
        assert!(doubts[0].contains("ill-conditioned"), "{doubts:?}");
    }

    #[test]
    fn the_detector_sigma_is_the_median() {
        assert_eq!(detector_sigma(&[0.3, 0.1, f64::NAN, 0.2]), 0.2);
        assert_eq!(detector_sigma(&[]), 0.0);
    }
}
