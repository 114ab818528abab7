//! Range checks that build [`ScenarioError::Invalid`] with the field's dotted path.

use super::ScenarioError;
use crate::frame::MAX_SIDE_PX;

/// Most pixels in one frame: 25 Mpx, above the largest machine-vision sensors in common
/// use (20 Mpx); a run holds a few dozen bytes per pixel of working images.
pub(crate) const MAX_IMAGE_PIXELS: u64 = 25_000_000;

/// Checks fields of one table, prefixing each field name with the table path.
pub(crate) struct Check<'a> {
    prefix: &'a str,
}

impl<'a> Check<'a> {
    pub(crate) fn new(prefix: &'a str) -> Self {
        Self { prefix }
    }

    /// The dotted path of `field` in this table.
    pub(crate) fn path(&self, field: &str) -> String {
        format!("{}.{}", self.prefix, field)
    }

    fn fail(&self, field: &str, reason: String) -> ScenarioError {
        ScenarioError::Invalid {
            field: self.path(field),
            reason,
        }
    }

    /// The value must be finite and strictly greater than `min`.
    pub(crate) fn gt(&self, field: &str, value: f64, min: f64) -> Result<(), ScenarioError> {
        if value.is_finite() && value > min {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be > {min}, got {value}")))
        }
    }

    /// The value must be finite and at least `min`.
    pub(crate) fn ge(&self, field: &str, value: f64, min: f64) -> Result<(), ScenarioError> {
        if value.is_finite() && value >= min {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be >= {min}, got {value}")))
        }
    }

    /// The value must be finite and within `min..=max`.
    pub(crate) fn within(
        &self,
        field: &str,
        value: f64,
        min: f64,
        max: f64,
    ) -> Result<(), ScenarioError> {
        if value.is_finite() && (min..=max).contains(&value) {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be within {min}..={max}, got {value}")))
        }
    }

    /// The value must be finite (any sign).
    pub(crate) fn finite(&self, field: &str, value: f64) -> Result<(), ScenarioError> {
        if value.is_finite() {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be finite, got {value}")))
        }
    }

    /// An image's `width_px` and `height_px`: each side at least 2 and at most
    /// [`MAX_SIDE_PX`], and at most [`MAX_IMAGE_PIXELS`] pixels in all.
    pub(crate) fn image_size(&self, width: u32, height: u32) -> Result<(), ScenarioError> {
        for (field, value) in [("width_px", width), ("height_px", height)] {
            if !(2..=MAX_SIDE_PX).contains(&value) {
                return Err(self.fail(
                    field,
                    format!("must be within 2..={MAX_SIDE_PX}, got {value}"),
                ));
            }
        }
        let pixels = u64::from(width) * u64::from(height);
        if pixels > MAX_IMAGE_PIXELS {
            return Err(self.fail(
                "width_px",
                format!(
                    "{width} x {height} is {pixels} pixels; at most {MAX_IMAGE_PIXELS} \
                     (a larger frame needs gigabytes per run)"
                ),
            ));
        }
        Ok(())
    }

    /// An offset range in motor steps: the hidden offset is drawn from `-value..=value`.
    pub(crate) fn offset_range(&self, field: &str, value: i32) -> Result<(), ScenarioError> {
        if value >= 0 {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be >= 0, got {value}")))
        }
    }

    /// Every entry of a 2x2 matrix must be finite and the matrix invertible, so that every
    /// beam position can be reached by some motor setting.
    pub(crate) fn matrix(&self, field: &str, m: &[[f64; 2]; 2]) -> Result<(), ScenarioError> {
        for (r, row) in m.iter().enumerate() {
            for (c, v) in row.iter().enumerate() {
                self.finite(&format!("{field}[{r}][{c}]"), *v)?;
            }
        }
        let det = m[0][0] * m[1][1] - m[0][1] * m[1][0];
        if det.abs() > 1e-12 {
            Ok(())
        } else {
            Err(self.fail(field, format!("must be invertible, got determinant {det}")))
        }
    }
}
