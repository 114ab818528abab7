//! Three-vectors for the relay's ray tracing (mm, table frame: x, y in the table plane,
//! z up).

use std::ops::{Add, Mul, Neg, Sub};

/// A vector or point in 3-D.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Vec3 {
    pub(crate) x: f64,
    pub(crate) y: f64,
    pub(crate) z: f64,
}

/// Straight up, out of the table.
pub(crate) const UP: Vec3 = Vec3::new(0.0, 0.0, 1.0);

impl Vec3 {
    pub(crate) const fn new(x: f64, y: f64, z: f64) -> Self {
        Self { x, y, z }
    }

    pub(crate) fn dot(self, o: Self) -> f64 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }

    pub(crate) fn cross(self, o: Self) -> Self {
        Self::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }

    pub(crate) fn norm(self) -> f64 {
        self.dot(self).sqrt()
    }

    pub(crate) fn normalized(self) -> Self {
        self * (1.0 / self.norm())
    }

    /// This vector rotated by `angle` (rad, right-handed) about the unit vector `axis`.
    pub(crate) fn rotated(self, axis: Self, angle: f64) -> Self {
        let (s, c) = angle.sin_cos();
        self * c + axis.cross(self) * s + axis * (axis.dot(self) * (1.0 - c))
    }

    /// This vector rotated by the rotation vector `r` (axis r / |r|, angle |r|).
    pub(crate) fn rotated_by(self, r: Self) -> Self {
        let angle = r.norm();
        if angle == 0.0 {
            self
        } else {
            self.rotated(r * (1.0 / angle), angle)
        }
    }

    /// The mirror image of a direction reflected off a surface with unit normal `n`.
    pub(crate) fn reflected(self, n: Self) -> Self {
        self - n * (2.0 * self.dot(n))
    }
}

impl Add for Vec3 {
    type Output = Self;
    fn add(self, o: Self) -> Self {
        Self::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}

impl Sub for Vec3 {
    type Output = Self;
    fn sub(self, o: Self) -> Self {
        Self::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}

impl Mul<f64> for Vec3 {
    type Output = Self;
    fn mul(self, s: f64) -> Self {
        Self::new(self.x * s, self.y * s, self.z * s)
    }
}

impl Neg for Vec3 {
    type Output = Self;
    fn neg(self) -> Self {
        self * -1.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: Vec3, b: Vec3) -> bool {
        (a - b).norm() < 1e-12
    }

    #[test]
    fn rotation_is_right_handed() {
        let x = Vec3::new(1.0, 0.0, 0.0);
        let y = Vec3::new(0.0, 1.0, 0.0);
        assert!(close(x.rotated(UP, std::f64::consts::FRAC_PI_2), y));
        assert!(close(x.rotated_by(UP * std::f64::consts::FRAC_PI_2), y));
        assert!(close(x.rotated_by(Vec3::new(0.0, 0.0, 0.0)), x));
    }

    #[test]
    fn reflection_off_a_45_degree_mirror_turns_90_degrees() {
        let d = Vec3::new(0.0, 1.0, 0.0);
        let n = Vec3::new(1.0, -1.0, 0.0).normalized();
        assert!(close(d.reflected(n), Vec3::new(1.0, 0.0, 0.0)));
        assert!(close(-d, Vec3::new(0.0, -1.0, 0.0)));
    }
}
