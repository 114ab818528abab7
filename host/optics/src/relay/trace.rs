//! Geometric ray tracing through the four tilted, circular mirrors: where the beam's centre
//! ray meets each mirror, how much of the finite-radius beam each aperture passes, and the
//! beam leaving each mirror.
//!
//! The beam is a collimated Gaussian of 1/e^2 radius w (sigma = w / 2). Its footprint on a
//! mirror is stretched by 1 / cos(incidence) along the plane of incidence; the fraction
//! inside the circular aperture is taken across the aperture edge nearest the hit point,
//! `Phi((R - rho) / sigma_eff)` (the edge is nearly straight on the beam's scale, R >> w).

use super::geometry::{UP, Vec3};
use super::layout::{Layout, Ray};
use crate::math::normal_cdf;
use crate::readout::mix64;
use crate::scenario::RelayParams;

/// Hit points on a clipping mirror are quantised to this size (mm) when choosing the speckle
/// pattern: the pattern changes whenever the clipping geometry changes by about this much.
const SPECKLE_DECORRELATION_MM: f64 = 0.02;

/// What happened at one mirror.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MirrorTruth {
    /// Fraction of the input power arriving at the mirror (0 when lost upstream).
    pub power_in: f64,
    /// Fraction of the arriving power reflected inside the aperture (0 when not reached).
    pub transmission: f64,
    /// Where the beam centre meets the mirror face, mm from the mirror centre in the face's
    /// (horizontal, vertical) axes; `None` when no light arrives or the ray misses the face's
    /// plane.
    pub hit_mm: Option<[f64; 2]>,
}

impl MirrorTruth {
    /// Light reached this mirror.
    pub fn reached(&self) -> bool {
        self.power_in > 0.0
    }

    /// Part of the arriving beam fell outside the aperture (more than one part in 10^4).
    pub fn clipped(&self) -> bool {
        self.reached() && self.transmission < 0.9999
    }
}

/// The light leaving one mirror.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Beam {
    pub(crate) ray: Ray,
    /// Fraction of the input power carried.
    pub(crate) power: f64,
    /// Identifies the clipping geometry upstream (selects the speckle pattern).
    pub(crate) clip_key: u64,
}

/// The result of tracing one set of mirror tilts.
#[derive(Debug, Clone)]
pub(crate) struct Trace {
    pub(crate) mirrors: [MirrorTruth; 4],
    /// The beam leaving mirror m, `None` once the light is lost.
    pub(crate) beams: [Option<Beam>; 4],
}

/// Traces the beam through the mirrors; `tilts_rad[2m]` and `tilts_rad[2m + 1]` are mirror
/// m's vertical and horizontal tilt.
pub(crate) fn trace(p: &RelayParams, layout: &Layout, tilts_rad: &[f64; 8]) -> Trace {
    let aperture = p.mirror_diameter_mm / 2.0;
    let sigma = p.beam_radius_mm / 2.0;
    let unreached = MirrorTruth {
        power_in: 0.0,
        transmission: 0.0,
        hit_mm: None,
    };
    let mut mirrors = [unreached; 4];
    let mut beams = [None; 4];
    let mut incoming = Some(Beam {
        ray: layout.input,
        power: 1.0,
        clip_key: 0,
    });
    for (m, frame) in layout.mirrors.iter().enumerate() {
        let Some(beam) = incoming else { break };
        mirrors[m].power_in = beam.power;
        // Tilt the face: vertical tilt about the face's horizontal axis, then horizontal tilt
        // about the vertical.
        let (tv, th) = (tilts_rad[2 * m], tilts_rad[2 * m + 1]);
        let normal = frame.normal.rotated(frame.horizontal, tv).rotated(UP, th);
        let u_axis = frame.horizontal.rotated(UP, th);
        let v_axis = normal.cross(u_axis);

        let d = beam.ray.dir;
        let dn = d.dot(normal);
        if dn >= -1e-9 {
            break;
        }
        let t = (frame.centre - beam.ray.origin).dot(normal) / dn;
        if t <= 0.0 {
            break;
        }
        let hit = beam.ray.origin + d * t;
        let rel = hit - frame.centre;
        let (u, v) = (rel.dot(u_axis), rel.dot(v_axis));
        mirrors[m].hit_mm = Some([u, v]);

        let transmission =
            aperture_transmission(aperture, sigma, [u, v], d, normal, u_axis, v_axis);
        mirrors[m].transmission = transmission;
        let power = beam.power * transmission;
        if power < p.light_threshold {
            break;
        }
        let clip_key = if transmission < 1.0 {
            let q = |x: f64| (x / SPECKLE_DECORRELATION_MM).round() as i64 as u64;
            mix64(beam.clip_key ^ mix64(q(u) ^ q(v).rotate_left(32) ^ m as u64))
        } else {
            beam.clip_key
        };
        let out = Beam {
            ray: Ray {
                origin: hit,
                dir: d.reflected(normal),
            },
            power,
            clip_key,
        };
        beams[m] = Some(out);
        incoming = Some(out);
    }
    Trace { mirrors, beams }
}

/// Fraction of a Gaussian beam (standard deviation `sigma` across the beam) falling inside a
/// circular aperture of radius `aperture`, for a centre ray hitting at `(u, v)` in the face.
fn aperture_transmission(
    aperture: f64,
    sigma: f64,
    hit: [f64; 2],
    dir: Vec3,
    normal: Vec3,
    u_axis: Vec3,
    v_axis: Vec3,
) -> f64 {
    let rho = hit[0].hypot(hit[1]);
    let cos_i = -dir.dot(normal);
    // Direction of the footprint's stretch within the face.
    let along = dir - normal * dir.dot(normal);
    let stretch = [along.dot(u_axis), along.dot(v_axis)];
    let stretch_len = stretch[0].hypot(stretch[1]);
    let alignment = if rho > 0.0 && stretch_len > 0.0 {
        (hit[0] * stretch[0] + hit[1] * stretch[1]) / (rho * stretch_len)
    } else {
        0.0
    };
    let elongation = 1.0 / (cos_i * cos_i) - 1.0;
    let sigma_eff = sigma * (1.0 + alignment * alignment * elongation).sqrt();
    normal_cdf((aperture - rho) / sigma_eff)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aligned_beam_passes_every_mirror_through_its_centre() {
        let p = RelayParams::default();
        let t = trace(&p, &Layout::new(&p), &[0.0; 8]);
        for m in t.mirrors {
            let [u, v] = m.hit_mm.unwrap();
            assert!(u.abs() < 1e-9 && v.abs() < 1e-9);
            assert_eq!(m.transmission, 1.0);
            assert!(!m.clipped());
        }
        assert!(t.beams.iter().all(|b| b.unwrap().power == 1.0));
    }

    #[test]
    fn beam_on_the_aperture_edge_loses_half_its_power() {
        let p = RelayParams::default();
        let normal = Vec3::new(1.0, -1.0, 0.0).normalized();
        let u_axis = UP.cross(normal).normalized();
        let v_axis = normal.cross(u_axis);
        let dir = Vec3::new(0.0, 1.0, 0.0);
        let edge = p.mirror_diameter_mm / 2.0;
        for hit in [[edge, 0.0], [0.0, edge]] {
            let t = aperture_transmission(edge, 0.5, hit, dir, normal, u_axis, v_axis);
            assert!((t - 0.5).abs() < 1e-6, "{t}");
        }
        // The footprint is longer along the plane of incidence: a hit 1 mm outside the edge
        // passes more light horizontally than vertically.
        let outside = edge + 1.0;
        let th = aperture_transmission(edge, 0.5, [outside, 0.0], dir, normal, u_axis, v_axis);
        let tv = aperture_transmission(edge, 0.5, [0.0, outside], dir, normal, u_axis, v_axis);
        assert!(th > tv && tv > 0.0, "{th} {tv}");
    }
}
