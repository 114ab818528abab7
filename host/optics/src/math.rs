//! Small numeric helpers: the normal distribution function and Gaussian profiles.

/// Complementary error function, fractional error below 1.2e-7 everywhere (Chebyshev fit).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let poly = -z * z - 1.265_512_23
        + t * (1.000_023_68
            + t * (0.374_091_96
                + t * (0.096_784_18
                    + t * (-0.186_288_06
                        + t * (0.278_868_07
                            + t * (-1.135_203_98
                                + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77))))))));
    let r = t * poly.exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// Standard normal cumulative distribution function.
pub fn normal_cdf(x: f64) -> f64 {
    0.5 * erfc(-x / std::f64::consts::SQRT_2)
}

/// Fraction of a 1-D Gaussian (centre `c`, standard deviation `sigma`) inside `[lo, hi]`.
pub(crate) fn gaussian_fraction(c: f64, sigma: f64, lo: f64, hi: f64) -> f64 {
    (normal_cdf((hi - c) / sigma) - normal_cdf((lo - c) / sigma)).max(0.0)
}

/// Half-width, in units of the 1/e^2 radius, beyond which a Gaussian spot is treated as
/// zero (its intensity there is below 1e-7 of the peak).
pub(crate) const SPOT_EXTENT: f64 = 2.9;

/// The pixel columns (or rows) `[0, n)` that a spot of 1/e^2 radius `radius` centred at
/// `centre` (pixel centres at i + 0.5) reaches.
pub(crate) fn spot_span(centre: f64, radius: f64, n: usize) -> std::ops::Range<usize> {
    let lo = (centre - SPOT_EXTENT * radius).floor().clamp(0.0, n as f64) as usize;
    let hi = (centre + SPOT_EXTENT * radius).ceil().clamp(0.0, n as f64) as usize;
    lo..hi.max(lo)
}

/// `exp(-2 ((i + 0.5 - centre) / radius)^2)` for each pixel `i` of `span`: the 1-D factor of
/// a Gaussian intensity profile with 1/e^2 radius `radius`.
pub(crate) fn gaussian_profile(centre: f64, radius: f64, span: std::ops::Range<usize>) -> Vec<f32> {
    span.map(|i| {
        let d = (i as f64 + 0.5 - centre) / radius;
        (-2.0 * d * d).exp() as f32
    })
    .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_cdf_matches_tabulated_values_deep_into_the_tail() {
        for (z, expected) in [
            (0.0, 0.5),
            (1.0, 0.841_344_746),
            (1.959_963_985, 0.975),
            (-2.0, 0.022_750_132),
            (-3.0, 0.001_349_898),
            (-6.0, 9.865_876e-10),
        ] {
            let got = normal_cdf(z);
            assert!(
                (got - expected).abs() <= 2e-7 * expected,
                "Φ({z}) = {got}, expected {expected}"
            );
        }
        assert_eq!(normal_cdf(40.0), 1.0);
    }

    #[test]
    fn spot_extent_keeps_the_tail_negligible() {
        // Intensity at the cut-off, relative to the peak.
        assert!((-2.0 * SPOT_EXTENT * SPOT_EXTENT).exp() < 1e-7);
    }

    #[test]
    fn spot_span_is_clipped_to_the_image() {
        assert_eq!(spot_span(-1000.0, 10.0, 100), 0..0);
        assert_eq!(spot_span(5.0, 10.0, 100), 0..34);
        assert_eq!(spot_span(5000.0, 10.0, 100), 100..100);
    }
}
