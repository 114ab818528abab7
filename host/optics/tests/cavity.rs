//! Behaviour of the cavity scene: linear secondary response, alignment, the secondary hiding
//! under the saturated primary, stationary artefacts, and determinism.

mod common;

use common::{centroid, max_diff, mean};
use optalign_optics::scenario::CavityParams;
use optalign_optics::seeds::{DEFAULT_SEEDS, cavity_offsets};
use optalign_optics::{Cavity, Frame};

/// Shaft that sends the secondary far off-screen for zero offsets.
const AWAY: [i32; 2] = [-40000, 40000];

fn quiet() -> CavityParams {
    let mut p = CavityParams::default();
    p.noise.std = 0.0;
    p
}

/// `a - b` per pixel (as floats) wrapped in a frame-like measurement: the secondary alone.
fn difference(a: &Frame, b: &Frame) -> Frame {
    let pixels = a
        .pixels()
        .iter()
        .zip(b.pixels())
        .map(|(x, y)| x.saturating_sub(*y))
        .collect();
    Frame::deep(a.width(), a.height(), pixels, a.full_scale()).unwrap()
}

#[test]
fn secondary_centre_is_linear_in_motor_steps_with_the_configured_sensitivity() {
    let p = quiet();
    let s = p.secondary.sensitivity_px_per_step;
    let scene = Cavity::new(p.clone(), [0; 2]).unwrap();
    let background = scene.render(&AWAY, 0);
    let primary = [640.0 + 25.0, 512.0 - 15.0];
    for shaft in [[-2500, 2000], [-2500, -2500], [3000, 0], [2500, 2800]] {
        let u = shaft.map(f64::from);
        let expected = [
            primary[0] + s[0][0] * u[0] + s[0][1] * u[1],
            primary[1] + s[1][0] * u[0] + s[1][1] * u[1],
        ];
        let secondary = difference(&scene.render(&shaft, 0), &background);
        let (measured, _) = centroid(&secondary, 0.0);
        for axis in 0..2 {
            assert!(
                (measured[axis] - expected[axis]).abs() < 0.5,
                "shaft {shaft:?}: centroid {measured:?}, expected {expected:?}"
            );
        }
        assert_eq!(scene.truth(&shaft).secondary_centre_px, expected);
    }
}

#[test]
fn negative_offsets_align_for_every_default_seed() {
    let p = CavityParams::default();
    for seed in DEFAULT_SEEDS {
        let offsets = cavity_offsets(&p, seed);
        let scene = Cavity::new(p.clone(), offsets).unwrap();
        let truth = scene.truth(&offsets.map(|o| -o));
        assert_eq!(truth.error_steps, 0.0);
        assert!(truth.success);
        assert_eq!(truth.secondary_centre_px, truth.primary_centre_px);
    }
}

#[test]
fn success_threshold_is_500_steps() {
    let scene = Cavity::new(CavityParams::default(), [0; 2]).unwrap();
    assert!(scene.truth(&[300, 400]).success);
    assert_eq!(scene.truth(&[300, 400]).error_steps, 500.0);
    assert!(!scene.truth(&[300, 401]).success);
}

#[test]
fn footprint_edge_is_about_500_steps_away() {
    let p = CavityParams::default();
    let scene = Cavity::new(p.clone(), [0; 2]).unwrap();
    for shaft in [[500, 0], [0, 500], [-354, 354]] {
        let t = scene.truth(&shaft);
        let d = (t.secondary_centre_px[0] - t.primary_centre_px[0])
            .hypot(t.secondary_centre_px[1] - t.primary_centre_px[1]);
        let ratio = d / p.primary.radius_px;
        assert!((0.8..1.2).contains(&ratio), "{shaft:?}: {d} px");
    }
}

#[test]
fn secondary_vanishes_under_the_saturated_primary_near_alignment() {
    let scene = Cavity::new(CavityParams::default(), [0; 2]).unwrap();
    let without = scene.render(&AWAY, 5);
    let aligned = scene.render(&[0, 0], 5);
    assert_eq!(aligned.pixel(665, 497), 255, "primary core saturates");
    assert!(max_diff(&aligned, &without, 0, 1280, 0, 1024) <= 1);
    // 2000 steps away the secondary stands out.
    let visible = scene.render(&[2000, 0], 5);
    assert!(max_diff(&visible, &without, 0, 1280, 0, 1024) > 25);
}

#[test]
fn primary_is_only_partly_saturated() {
    let scene = Cavity::new(quiet(), [0; 2]).unwrap();
    let frame = scene.render(&AWAY, 0);
    let centre_row = 497;
    assert_eq!(frame.pixel(665, centre_row), 255);
    let edge = frame.pixel(665 + 70, centre_row);
    assert!((100..255).contains(&edge), "edge {edge}");
}

#[test]
fn ring_halo_and_ghosts_stay_put_when_the_motors_move() {
    let scene = Cavity::new(CavityParams::default(), [0; 2]).unwrap();
    // The secondary in the top-left corner, then in the bottom-right: far from the artefacts.
    let a = [4000, -3000];
    let b = [-3000, 3000];
    let regions = [
        (890, 1010, 262, 382), // ghost 1 at (950, 322)
        (230, 290, 722, 782),  // ghost 2 at (260, 752)
        (655, 675, 657, 677),  // ring below the primary
        (485, 505, 487, 507),  // ring left of the primary
    ];
    let (fa, fb) = (scene.render(&a, 9), scene.render(&b, 9));
    for (x0, x1, y0, y1) in regions {
        // Same frame index: same noise, so the regions are identical.
        assert_eq!(max_diff(&fa, &fb, x0, x1, y0, y1), 0);
        // Different noise: the same picture apart from noise.
        let fc = scene.render(&b, 10);
        assert!((mean(&fa, x0, x1, y0, y1) - mean(&fc, x0, x1, y0, y1)).abs() < 0.5);
    }
    // The artefacts are really there: brighter than the background.
    let bg = mean(&fa, 1100, 1200, 50, 150);
    assert!(mean(&fa, 935, 965, 307, 337) > bg + 20.0);
    assert!(mean(&fa, 662, 668, 664, 670) > bg + 12.0);
}

#[test]
fn far_seeds_start_off_screen() {
    let p = CavityParams::default();
    let off_screen = DEFAULT_SEEDS
        .filter(|&seed| {
            let scene = Cavity::new(p.clone(), cavity_offsets(&p, seed)).unwrap();
            let c = scene.truth(&[0, 0]).secondary_centre_px;
            !(0.0..1280.0).contains(&c[0]) || !(0.0..1024.0).contains(&c[1])
        })
        .count();
    assert!(
        (1..10).contains(&off_screen),
        "{off_screen} of 10 seeds off-screen"
    );
}

#[test]
fn rendering_is_deterministic_per_seed_and_frame_index() {
    let p = CavityParams::default();
    let offsets = cavity_offsets(&p, 2);
    let a = Cavity::new(p.clone(), offsets).unwrap();
    let b = Cavity::new(p, offsets).unwrap();
    assert_eq!(a.render(&[10, 20], 3), b.render(&[10, 20], 3));
    assert_ne!(a.render(&[10, 20], 3), a.render(&[10, 20], 4));
}
