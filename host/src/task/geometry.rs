//! What is known about a bench's geometry, told to every policy in its brief. Each field is
//! optional: a rig file gives what its owner measured (`[geometry]`), a scenario what the
//! simulation is built with. Nothing here is a promise: the agents measure responses and
//! scales from the images and use these values only where they are geometry (a lever-arm
//! ratio, how far apart the stations are), and the language model reads them in its prompt.

use serde::{Deserialize, Serialize};

/// A bench's geometry, as far as it is known.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct BenchGeometry {
    /// Camera sensor width and height, mm.
    pub sensor_mm: Option<[f64; 2]>,
    /// Camera image width and height, px.
    pub image_px: Option<[u32; 2]>,
    /// Mirror tilt per motor step, rad (a datasheet value: the real response is measured).
    pub tilt_rad_per_step: Option<f64>,
    /// Relay: the long and the short side of the mirrors' rectangle, mm.
    pub relay_sides_mm: Option<[f64; 2]>,
    /// Relay: the mirrors' diameter, mm.
    pub mirror_diameter_mm: Option<f64>,
    /// Relay: each station's distance from the mirror that starts its segment, mm (C1..C8).
    pub station_distances_mm: Option<[f64; 8]>,
    /// Relay: how repeatably the camera mover places the camera at a station, mm (the
    /// standard deviation of its position across the beam, per axis, from one placement to
    /// the next).
    pub placement_repeatability_mm: Option<f64>,
}

impl BenchGeometry {
    /// Checks the values given; errors name `<table>.<field>`.
    pub fn validate(&self, table: &str) -> Result<(), String> {
        let positive = |field: &str, value: f64| {
            if value.is_finite() && value > 0.0 {
                Ok(())
            } else {
                Err(format!("{table}.{field}: must be > 0, got {value}"))
            }
        };
        if let Some([w, h]) = self.sensor_mm {
            positive("sensor_mm[0]", w)?;
            positive("sensor_mm[1]", h)?;
        }
        if let Some([w, h]) = self.image_px {
            positive("image_px[0]", f64::from(w))?;
            positive("image_px[1]", f64::from(h))?;
        }
        if let Some(tilt) = self.tilt_rad_per_step {
            positive("tilt_rad_per_step", tilt)?;
        }
        if let Some([long, short]) = self.relay_sides_mm {
            positive("relay_sides_mm[0]", long)?;
            positive("relay_sides_mm[1]", short)?;
        }
        if let Some(d) = self.mirror_diameter_mm {
            positive("mirror_diameter_mm", d)?;
        }
        if let Some(spread) = self.placement_repeatability_mm {
            positive("placement_repeatability_mm", spread)?;
        }
        if let Some(distances) = self.station_distances_mm {
            for (i, d) in distances.iter().enumerate() {
                positive(&format!("station_distances_mm[{i}]"), *d)?;
            }
        }
        Ok(())
    }

    /// The pixel pitch (x, y), mm, when both the sensor size and the image size are known.
    pub fn pixel_pitch_mm(&self) -> Option<[f64; 2]> {
        let [w, h] = self.sensor_mm?;
        let [pw, ph] = self.image_px?;
        Some([w / f64::from(pw), h / f64::from(ph)])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bad_values_name_the_field_and_the_pitch_follows_from_the_sensor() {
        let geometry = BenchGeometry {
            sensor_mm: Some([6.4, 4.8]),
            image_px: Some([640, 480]),
            ..BenchGeometry::default()
        };
        assert_eq!(geometry.pixel_pitch_mm(), Some([0.01, 0.01]));
        assert!(geometry.validate("geometry").is_ok());
        let bad = BenchGeometry {
            station_distances_mm: Some([25.0, 254.4, 25.0, -1.0, 25.0, 254.4, 25.0, 300.0]),
            ..BenchGeometry::default()
        };
        let error = bad.validate("geometry").unwrap_err();
        assert!(
            error.contains("geometry.station_distances_mm[3]"),
            "{error}"
        );
        assert_eq!(BenchGeometry::default().pixel_pitch_mm(), None);
    }
}
