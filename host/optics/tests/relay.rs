//! Behaviour of the relay scene: alignment, darkness at C8 for the default seeds, lost light
//! downstream of a missed mirror, spot motion, speckle when clipped, placement error and
//! determinism.

mod common;

use common::{centroid, mean};
use optalign_optics::scenario::RelayParams;
use optalign_optics::seeds::{DEFAULT_SEEDS, relay_offsets};
use optalign_optics::{CameraPose, Frame, Relay, Station};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Offsets of a moderately misaligned relay used where the seed does not matter.
const OFFSETS: [i32; 8] = [3000, -4000, 2500, 1000, -500, 7000, 1500, -2500];

fn aligned() -> [i32; 8] {
    OFFSETS.map(|o| -o)
}

fn quiet() -> RelayParams {
    let mut p = RelayParams::default();
    p.noise.std = 0.0;
    p.noise.background_level = 0.0;
    p
}

/// A frame with nothing but background and noise: no pixel far above the background.
fn is_dark(frame: &Frame, p: &RelayParams) -> bool {
    let limit = p.noise.background_level + 7.0 * p.noise.std + 1.0;
    frame.pixels().iter().all(|&v| f64::from(v) <= limit)
}

#[test]
fn negative_offsets_give_a_centred_spot_at_every_station() {
    let p = quiet();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    let truth = scene.truth(&aligned());
    for m in &truth.mirrors {
        assert!(m.reached() && !m.clipped());
        assert_eq!(m.transmission, 1.0);
    }
    for (i, s) in truth.stations.iter().enumerate() {
        assert!(s.lit, "C{}", i + 1);
        let [x, y] = s.offset_px.unwrap();
        assert!(x.abs() < 1e-9 && y.abs() < 1e-9, "C{}: {x} {y}", i + 1);
    }
    let [x, y] = truth.c8_offset_px.unwrap();
    assert!(x.hypot(y) < 1e-9);
    for station in Station::ALL {
        let frame = scene.render(&aligned(), &CameraPose::nominal(station), 0);
        let (c, _) = centroid(&frame, 0.0);
        assert!(
            (c[0] - 320.0).abs() < 0.5 && (c[1] - 240.0).abs() < 0.5,
            "{station}: {c:?}"
        );
        assert!(frame.pixel(320, 240) > 200);
    }
}

#[test]
fn default_seeds_leave_c8_dark_and_mostly_light_c1() {
    let p = RelayParams::default();
    let mut c1_lit = 0;
    for seed in DEFAULT_SEEDS {
        let offsets = relay_offsets(&p, seed).unwrap();
        let scene = Relay::new(p.clone(), offsets).unwrap();
        let truth = scene.truth(&[0; 8]);
        assert_eq!(truth.c8_offset_px, None, "seed {seed}");
        assert!(!truth.stations[7].lit);
        let c8 = scene.render(&[0; 8], &CameraPose::nominal(Station::C8), 0);
        assert!(is_dark(&c8, &p), "seed {seed}: light at C8");
        let c1 = scene.render(&[0; 8], &CameraPose::nominal(Station::C1), 0);
        if truth.stations[0].lit && !is_dark(&c1, &p) {
            c1_lit += 1;
        }
    }
    assert!(
        c1_lit >= 7,
        "beam visible at C1 for only {c1_lit} of 10 seeds"
    );
}

#[test]
fn tilting_m2_off_m3_darkens_c4_to_c8_but_not_c3() {
    let p = RelayParams::default();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    // The vertical tilt deflects by 2 theta cos 45 deg, so it needs more steps.
    for (axis, steps) in [(2, 8000), (3, 6000)] {
        let mut shaft = aligned();
        shaft[axis] += steps;
        let truth = scene.truth(&shaft);
        assert!(truth.mirrors[1].reached() && !truth.mirrors[1].clipped());
        assert!(truth.mirrors[2].transmission < 0.01, "axis {axis}");
        assert!(!truth.mirrors[3].reached());
        assert!(truth.stations[2].lit, "C3 stays lit (axis {axis})");
        for (i, s) in truth.stations.iter().enumerate().skip(3) {
            assert!(!s.lit, "C{} lit (axis {axis})", i + 1);
        }
        let c3 = scene.render(&shaft, &CameraPose::nominal(Station::C3), 0);
        assert!(!is_dark(&c3, &p));
        for station in &Station::ALL[3..] {
            let frame = scene.render(&shaft, &CameraPose::nominal(*station), 0);
            assert!(is_dark(&frame, &p), "{station} not dark (axis {axis})");
        }
    }
}

#[test]
fn tilting_m1_off_m2_darkens_c3_to_c8() {
    let p = RelayParams::default();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    for axis in [0, 1] {
        let mut shaft = aligned();
        shaft[axis] -= 6000;
        let truth = scene.truth(&shaft);
        assert!(truth.stations[0].lit, "C1 stays lit (axis {axis})");
        assert!(!truth.mirrors[2].reached());
        let c1 = scene.render(&shaft, &CameraPose::nominal(Station::C1), 0);
        assert!(!is_dark(&c1, &p));
        for station in &Station::ALL[2..] {
            assert!(!truth.stations[station.index()].lit);
            let frame = scene.render(&shaft, &CameraPose::nominal(*station), 0);
            assert!(is_dark(&frame, &p), "{station} not dark (axis {axis})");
        }
    }
}

#[test]
fn spot_moves_linearly_with_tilt_by_twice_the_mirror_angle() {
    let p = quiet();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    let pitch = p.camera.sensor_width_mm / f64::from(p.camera.width_px);
    let lever = p.station_distances_mm[0];
    let pose = CameraPose::nominal(Station::C1);
    let shift = |axis: usize, steps: i32| {
        let mut shaft = aligned();
        shaft[axis] += steps;
        let (c, _) = centroid(&scene.render(&shaft, &pose, 0), 0.0);
        let truth = scene.truth(&shaft).stations[0].offset_px.unwrap();
        assert!((truth[0] - (c[0] - 320.0)).abs() < 0.5 && (truth[1] - (c[1] - 240.0)).abs() < 0.5);
        [c[0] - 320.0, c[1] - 240.0]
    };
    // Image-x shift per step of M1's horizontal axis, image-y shift per step of its vertical
    // axis: the beam turns by twice the tilt, and a vertical tilt of a 45 degree mirror
    // deflects by 2 theta cos 45 deg.
    let per_step_h = shift(1, 100)[0] / 100.0;
    let per_step_v = shift(0, 100)[1] / 100.0;
    let nominal = 2.0 * p.tilt_rad_per_step * lever / pitch;
    assert!(
        (per_step_h.abs() / nominal - 1.0).abs() < 0.05,
        "{per_step_h}"
    );
    assert!(
        (per_step_v.abs() / (nominal * std::f64::consts::FRAC_1_SQRT_2) - 1.0).abs() < 0.05,
        "{per_step_v}"
    );
    for steps in [-1500, -500, 500, 1500] {
        let h = shift(1, steps);
        assert!((h[0] - per_step_h * f64::from(steps)).abs() < 0.5 && h[1].abs() < 0.5);
        let v = shift(0, steps);
        assert!((v[1] - per_step_v * f64::from(steps)).abs() < 0.5 && v[0].abs() < 0.5);
    }
}

#[test]
fn a_clipped_beam_shows_speckle_instead_of_a_spot() {
    let p = quiet();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    let set = |base: [i32; 8], axis: usize, value: i32| {
        let mut s = base;
        s[axis] = value;
        s
    };
    let station = Station::C4;
    let lateral = |s: &[i32; 8]| {
        scene.truth(s).stations[station.index()]
            .offset_px
            .map_or(f64::INFINITY, |o| o[0].abs())
    };
    let half_clipped =
        |s: &[i32; 8]| (0.45..0.55).contains(&scene.truth(s).mirrors[1].transmission);
    // Alternately walk M1's horizontal tilt until the beam half-clips on M2's edge, and steer
    // M2 so that what passes lands on C4 (steering M2 moves the hit point on its face a little).
    let mut shaft = aligned();
    for _ in 0..3 {
        let base = shaft;
        shaft = (1000..5000)
            .step_by(2)
            .map(|extra| set(base, 1, aligned()[1] + extra))
            .find(|s| half_clipped(s))
            .expect("some tilt half-clips the beam on M2");
        let base = shaft;
        shaft = (-8000..8000)
            .step_by(5)
            .map(|extra| set(base, 3, aligned()[3] + extra))
            .min_by(|a, b| lateral(a).total_cmp(&lateral(b)))
            .unwrap();
    }
    assert!((0.3..0.7).contains(&scene.truth(&shaft).mirrors[1].transmission));
    let truth = scene.truth(&shaft);
    assert!(truth.mirrors[1].clipped());
    assert!(truth.stations[station.index()].lit);
    let [ox, oy] = truth.stations[station.index()].offset_px.unwrap();
    let (hx, hy) = ((320.0 + ox) as u32, (240.0 + oy) as u32);
    assert!(
        (50..590).contains(&hx) && (50..430).contains(&hy),
        "hit at {hx} {hy}"
    );
    let speckle = scene.render(&shaft, &CameraPose::nominal(station), 0);
    let spot = scene.render(&aligned(), &CameraPose::nominal(station), 0);
    let core = |f: &Frame, cx: u32, cy: u32| mean(f, cx - 10, cx + 10, cy - 10, cy + 10);
    // No bright core where the beam lands, but far more light than a dark frame.
    assert!(core(&spot, 320, 240) > 180.0);
    assert!(
        core(&speckle, hx, hy) < 60.0,
        "core {}",
        core(&speckle, hx, hy)
    );
    assert!(!is_dark(&speckle, &p));
    // Granular: neighbouring pixels differ far more than in a clean spot.
    let roughness = |f: &Frame, cx: u32, cy: u32| {
        let mut sum = 0.0;
        for y in cy - 40..cy + 40 {
            for x in cx - 40..cx + 40 {
                sum += f64::from(f.pixel(x + 1, y).abs_diff(f.pixel(x, y)));
            }
        }
        sum / 6400.0
    };
    let (rough_speckle, rough_spot) = (roughness(&speckle, hx, hy), roughness(&spot, 320, 240));
    assert!(
        rough_speckle > 3.0 * rough_spot,
        "{rough_speckle} vs {rough_spot}"
    );
}

#[test]
fn a_beam_partly_off_the_sensor_shows_speckle_and_one_well_inside_a_spot() {
    let p = quiet();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    let pose = CameraPose::nominal(Station::C1);
    let hit_x = |shaft: &[i32; 8]| scene.truth(shaft).stations[0].offset_px.unwrap()[0];
    // Walk M1's horizontal tilt until the beam centre sits `x_px` from the image centre.
    let at = |x_px: f64| {
        (0..20_000)
            .step_by(5)
            .map(|extra| {
                let mut shaft = aligned();
                shaft[1] += extra;
                shaft
            })
            .min_by(|a, b| {
                (hit_x(a).abs() - x_px)
                    .abs()
                    .total_cmp(&(hit_x(b).abs() - x_px).abs())
            })
            .unwrap()
    };
    let roughness = |f: &Frame, cx: u32| {
        let mut sum = 0.0;
        for y in 200..280 {
            for x in cx - 15..cx + 15 {
                sum += f64::from(f.pixel(x + 1, y).abs_diff(f.pixel(x, y)));
            }
        }
        sum / 2400.0
    };
    // A third of the beam falls past the edge (1 mm beam radius, 3.2 mm half-width).
    let (edge_shaft, inside_shaft) = (at(300.0), at(100.0));
    let edge = scene.render(&edge_shaft, &pose, 0);
    let inside = scene.render(&inside_shaft, &pose, 0);
    let near_edge = hit_x(&edge_shaft);
    // Sample 20 px from the beam centre towards the image centre (still on the sensor).
    let edge_x = (320.0 + near_edge - 20.0 * near_edge.signum()) as u32;
    let inside_x = (320.0 + hit_x(&inside_shaft)) as u32;
    assert!(
        mean(&inside, inside_x - 10, inside_x + 10, 230, 250) > 180.0,
        "a clean spot well inside"
    );
    let (edge_core, inside_core) = (
        mean(&edge, edge_x - 10, edge_x + 10, 230, 250),
        mean(&inside, inside_x - 10, inside_x + 10, 230, 250),
    );
    assert!(
        edge_core < 0.4 * inside_core,
        "no bright core at the edge: beam at {near_edge} px, core {edge_core} vs {inside_core}"
    );
    assert!(!is_dark(&edge, &p));
    assert!(
        roughness(&edge, edge_x) > 3.0 * roughness(&inside, inside_x),
        "speckle, not a cut spot"
    );
}

#[test]
fn camera_placement_error_shifts_the_spot_and_is_reproducible() {
    let p = quiet();
    let scene = Relay::new(p.clone(), OFFSETS).unwrap();
    let mut rng_a = ChaCha8Rng::seed_from_u64(11);
    let mut rng_b = ChaCha8Rng::seed_from_u64(11);
    let pose_a = CameraPose::place(Station::C5, &p.camera, &mut rng_a);
    let pose_b = CameraPose::place(Station::C5, &p.camera, &mut rng_b);
    assert_eq!(pose_a, pose_b);
    assert_ne!(pose_a, CameraPose::nominal(Station::C5));
    assert_eq!(
        scene.render(&aligned(), &pose_a, 2),
        scene.render(&aligned(), &pose_b, 2)
    );
    // A pure sideways shift of the camera moves the spot the other way.
    let shifted = CameraPose {
        offset_mm: [0.2, -0.1, 0.0],
        ..CameraPose::nominal(Station::C5)
    };
    let (c, _) = centroid(&scene.render(&aligned(), &shifted, 0), 0.0);
    assert!(
        (c[0] - (320.0 - 20.0)).abs() < 0.5 && (c[1] - (240.0 + 10.0)).abs() < 0.5,
        "{c:?}"
    );
}

#[test]
fn rendering_is_deterministic_per_seed_and_frame_index() {
    let p = RelayParams::default();
    let offsets = relay_offsets(&p, 6).unwrap();
    let a = Relay::new(p.clone(), offsets).unwrap();
    let b = Relay::new(p, offsets).unwrap();
    let pose = CameraPose::nominal(Station::C1);
    assert_eq!(a.render(&[0; 8], &pose, 1), b.render(&[0; 8], &pose, 1));
    assert_ne!(a.render(&[0; 8], &pose, 1), a.render(&[0; 8], &pose, 2));
}
