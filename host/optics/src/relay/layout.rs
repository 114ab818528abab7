//! The relay's nominal optical layout: mirror positions and orientations on the table, the
//! input beam, and the eight camera station planes.
//!
//! Table frame, mm, z up, beam height z = 0. M1 at (0, 0), M2 at (L, 0), M3 at (L, S),
//! M4 at (0, S) with L = `long_side_mm`, S = `short_side_mm`. The input travels +y into M1;
//! the nominal path then runs +x (M1->M2), +y (M2->M3), -x (M3->M4) and leaves M4 along +y.
//! Every mirror turns the beam by 90 degrees in the table plane.

use super::geometry::{UP, Vec3};
use crate::scenario::RelayParams;

/// A straight ray: the beam's centre line.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Ray {
    pub(crate) origin: Vec3,
    pub(crate) dir: Vec3,
}

/// A mirror at rest (zero tilt).
#[derive(Debug, Clone, Copy)]
pub(crate) struct MirrorFrame {
    /// Centre of the reflecting face, which is also the tilt pivot.
    pub(crate) centre: Vec3,
    /// Unit normal of the face, pointing towards the incoming beam.
    pub(crate) normal: Vec3,
    /// Unit vector in the face, horizontal: the axis of the vertical tilt.
    pub(crate) horizontal: Vec3,
}

/// A camera plane: origin at the sensor centre, normal along the beam.
#[derive(Debug, Clone, Copy)]
pub(crate) struct PlaneFrame {
    pub(crate) origin: Vec3,
    /// Image x (right, as seen looking along the beam).
    pub(crate) x: Vec3,
    /// Image y (down).
    pub(crate) y: Vec3,
    /// Along the nominal beam.
    pub(crate) normal: Vec3,
}

impl PlaneFrame {
    /// The frame moved by `offset` (mm, in this frame's x, y, normal) and rotated by the small
    /// rotation vector `rotation` (rad, in this frame's x, y, normal).
    pub(crate) fn perturbed(&self, offset: [f64; 3], rotation: [f64; 3]) -> Self {
        let in_frame = |v: [f64; 3]| self.x * v[0] + self.y * v[1] + self.normal * v[2];
        let r = in_frame(rotation);
        Self {
            origin: self.origin + in_frame(offset),
            x: self.x.rotated_by(r),
            y: self.y.rotated_by(r),
            normal: self.normal.rotated_by(r),
        }
    }

    /// Where `ray` crosses this plane, in plane coordinates (mm); `None` if it runs parallel
    /// to the plane or crosses it behind its origin.
    pub(crate) fn intersect(&self, ray: &Ray) -> Option<[f64; 2]> {
        let denom = ray.dir.dot(self.normal);
        if denom <= 1e-9 {
            return None;
        }
        let t = (self.origin - ray.origin).dot(self.normal) / denom;
        if t <= 0.0 {
            return None;
        }
        let rel = ray.origin + ray.dir * t - self.origin;
        Some([rel.dot(self.x), rel.dot(self.y)])
    }
}

/// Everything fixed about the relay's geometry.
#[derive(Debug, Clone)]
pub(crate) struct Layout {
    pub(crate) input: Ray,
    pub(crate) mirrors: [MirrorFrame; 4],
    pub(crate) stations: [PlaneFrame; 8],
}

impl Layout {
    pub(crate) fn new(p: &RelayParams) -> Self {
        let (l, s) = (p.long_side_mm, p.short_side_mm);
        let centres = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(l, 0.0, 0.0),
            Vec3::new(l, s, 0.0),
            Vec3::new(0.0, s, 0.0),
        ];
        // Nominal beam direction before M1, after M1, ..., after M4.
        let dirs = [
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let mirrors = std::array::from_fn(|m| {
            let normal = (dirs[m + 1] - dirs[m]).normalized();
            MirrorFrame {
                centre: centres[m],
                normal,
                horizontal: UP.cross(normal).normalized(),
            }
        });
        let stations = std::array::from_fn(|i| {
            let segment = i / 2;
            let dir = dirs[segment + 1];
            PlaneFrame {
                origin: centres[segment] + dir * p.station_distances_mm[i],
                x: dir.cross(UP),
                y: -UP,
                normal: dir,
            }
        });
        Self {
            input: Ray {
                origin: centres[0] - dirs[0] * 100.0,
                dir: dirs[0],
            },
            mirrors,
            stations,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stations_sit_on_the_nominal_path_facing_the_beam() {
        let p = RelayParams::default();
        let layout = Layout::new(&p);
        let c2 = &layout.stations[1];
        assert!((c2.origin - Vec3::new(254.4, 0.0, 0.0)).norm() < 1e-9);
        assert!((c2.x - Vec3::new(0.0, -1.0, 0.0)).norm() < 1e-12);
        let ray = Ray {
            origin: Vec3::new(0.0, 0.0, 0.0),
            dir: Vec3::new(1.0, 0.0, 0.0),
        };
        assert_eq!(c2.intersect(&ray), Some([0.0, 0.0]));
        let backwards = Ray {
            dir: Vec3::new(-1.0, 0.0, 0.0),
            ..ray
        };
        assert_eq!(c2.intersect(&backwards), None);
    }

    #[test]
    fn perturbed_frame_stays_orthonormal() {
        let layout = Layout::new(&RelayParams::default());
        let f = layout.stations[4].perturbed([0.1, -0.2, 0.3], [0.01, -0.02, 0.03]);
        assert!((f.x.norm() - 1.0).abs() < 1e-12);
        assert!(f.x.dot(f.y).abs() < 1e-12);
        assert!(f.x.cross(f.y).dot(f.normal) > 0.999);
    }
}
