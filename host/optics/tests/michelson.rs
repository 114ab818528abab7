//! Behaviour of the Michelson scene: linear beam response, alignment, fringes, clipping,
//! noise and determinism.

mod common;

use common::{centroid, mean};
use optalign_optics::scenario::MichelsonParams;
use optalign_optics::seeds::{DEFAULT_SEEDS, michelson_offsets};
use optalign_optics::{Frame, Michelson};

/// Default parameters without noise or background, so pixels are pure beam intensity.
fn quiet() -> MichelsonParams {
    let mut p = MichelsonParams::default();
    p.noise.std = 0.0;
    p.noise.background_level = 0.0;
    p
}

/// Beam 2 far off-screen (mirror 2 shafts), leaving beam 1 alone on the image.
const BEAM_2_AWAY: [i32; 2] = [30000, 30000];

#[test]
fn beam_centre_is_linear_in_motor_steps_with_the_configured_sensitivity() {
    let p = quiet();
    let s = p.mirror_1_sensitivity_px_per_step;
    let offsets = [300, -200, 0, 0];
    let scene = Michelson::new(p, offsets).unwrap();
    for shaft_1 in [[0, 0], [1500, 0], [0, -1200], [-2000, 1000]] {
        let shaft = [shaft_1[0], shaft_1[1], BEAM_2_AWAY[0], BEAM_2_AWAY[1]];
        let u = [
            f64::from(shaft_1[0] + offsets[0]),
            f64::from(shaft_1[1] + offsets[1]),
        ];
        let expected = [
            960.0 + s[0][0] * u[0] + s[0][1] * u[1],
            540.0 + s[1][0] * u[0] + s[1][1] * u[1],
        ];
        let (measured, _) = centroid(&scene.render(&shaft, 0), 0.0);
        for axis in 0..2 {
            assert!(
                (measured[axis] - expected[axis]).abs() < 0.3,
                "shaft {shaft:?}: centroid {measured:?}, expected {expected:?}"
            );
        }
        assert_eq!(scene.truth(&shaft).beam_centres_px[0], expected);
    }
}

#[test]
fn negative_offsets_align_both_beams_on_the_centre_for_every_default_seed() {
    let p = MichelsonParams::default();
    for seed in DEFAULT_SEEDS {
        let offsets = michelson_offsets(&p, seed);
        let scene = Michelson::new(p.clone(), offsets).unwrap();
        let aligned = offsets.map(|o| -o);
        let truth = scene.truth(&aligned);
        assert_eq!(truth.error_px, 0.0, "seed {seed}");
        assert_eq!(truth.beam_centres_px, [[960.0, 540.0]; 2]);
        assert!(scene.truth(&[0; 4]).error_px > 0.0);
    }
    let quiet_scene = Michelson::new(quiet(), [1000, -700, 2000, 300]).unwrap();
    let (c, _) = centroid(&quiet_scene.render(&[-1000, 700, -2000, -300], 0), 0.0);
    assert!(
        (c[0] - 960.0).abs() < 1.0 && (c[1] - 540.0).abs() < 1.0,
        "{c:?}"
    );
}

#[test]
fn error_is_the_sum_of_both_beam_distances() {
    let p = MichelsonParams::default();
    let scene = Michelson::new(p.clone(), [0; 4]).unwrap();
    let truth = scene.truth(&[1000, 0, 0, -500]);
    let s1 = p.mirror_1_sensitivity_px_per_step;
    let s2 = p.mirror_2_sensitivity_px_per_step;
    let d1 = (s1[0][0] * 1000.0).hypot(s1[1][0] * 1000.0);
    let d2 = (s2[0][1] * 500.0).hypot(s2[1][1] * 500.0);
    assert!((truth.error_px - (d1 + d2)).abs() < 1e-9);
}

/// Gray levels along the phase-gradient direction through `(cx, cy)`, offsets `-n..=n`.
fn along_gradient(frame: &Frame, p: &MichelsonParams, cx: f64, cy: f64, n: i32) -> Vec<u16> {
    let a = p.fringe_angle_deg.to_radians();
    (-n..=n)
        .map(|t| {
            let x = cx + f64::from(t) * a.cos();
            let y = cy + f64::from(t) * a.sin();
            frame.pixel(x.floor() as u32, y.floor() as u32)
        })
        .collect()
}

#[test]
fn fringes_appear_where_the_beams_overlap() {
    let p = quiet();
    let scene = Michelson::new(p.clone(), [0; 4]).unwrap();
    let frame = scene.render(&[0; 4], 0);
    let line = along_gradient(&frame, &p, 960.0, 540.0, 60);
    let (max, min) = (*line.iter().max().unwrap(), *line.iter().min().unwrap());
    // Constructive interference saturates, destructive leaves almost nothing.
    assert!(max == 255 && min < 5, "max {max} min {min}");
    // Dark fringes (runs of dark samples) are one fringe period apart.
    let mut dark = Vec::new();
    let mut run_start = None;
    for (i, &v) in line.iter().enumerate() {
        match (v < 20, run_start) {
            (true, None) => run_start = Some(i),
            (false, Some(start)) => {
                dark.push((start + i - 1) as f64 / 2.0);
                run_start = None;
            }
            _ => {}
        }
    }
    assert!(dark.len() >= 2, "dark fringes at {dark:?}");
    for pair in dark.windows(2) {
        assert!(
            (pair[1] - pair[0] - p.fringe_period_px).abs() <= 2.0,
            "dark fringes at {dark:?}"
        );
    }
}

#[test]
fn a_single_beam_shows_no_fringes() {
    let p = quiet();
    let scene = Michelson::new(p.clone(), [0; 4]).unwrap();
    // Beam 1 500 px left of centre, beam 2 500 px right: they do not overlap.
    let s1 = p.mirror_1_sensitivity_px_per_step;
    let s2 = p.mirror_2_sensitivity_px_per_step;
    let steps = |s: [[f64; 2]; 2], dx: f64| {
        // Solve s * u = (dx, 0).
        let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
        [
            (s[1][1] * dx / det).round() as i32,
            (-s[1][0] * dx / det).round() as i32,
        ]
    };
    let (u1, u2) = (steps(s1, -500.0), steps(s2, 500.0));
    let shaft = [u1[0], u1[1], u2[0], u2[1]];
    let truth = scene.truth(&shaft);
    let frame = scene.render(&shaft, 0);
    for (k, c) in truth.beam_centres_px.iter().enumerate() {
        let line = along_gradient(&frame, &p, c[0], c[1], 80);
        let a = p.fringe_angle_deg.to_radians();
        for (i, &v) in line.iter().enumerate() {
            // The plain Gaussian profile of beam k alone, at the sampled pixel's centre.
            let t = i as f64 - 80.0;
            let x = (c[0] + t * a.cos()).floor() + 0.5;
            let y = (c[1] + t * a.sin()).floor() + 0.5;
            let r2 = (x - c[0]).powi(2) + (y - c[1]).powi(2);
            let expected = p.beam_peak_level[k] * (-2.0 * r2 / p.beam_radius_px[k].powi(2)).exp();
            assert!(
                (f64::from(v) - expected).abs() <= 1.0,
                "beam {k} at {t}: {v} vs {expected}"
            );
        }
    }
}

#[test]
fn beams_partly_off_screen_are_cut_at_the_border() {
    let p = quiet();
    let scene = Michelson::new(p.clone(), [0; 4]).unwrap();
    // Beam 1 centred 40 px left of the image (x = -40), beam 2 away.
    let s = p.mirror_1_sensitivity_px_per_step;
    let u0 = (-1000.0 / s[0][0]).round() as i32;
    let shaft = [u0, 0, BEAM_2_AWAY[0], BEAM_2_AWAY[1]];
    let c = scene.truth(&shaft).beam_centres_px[0];
    assert!(c[0] < 0.0);
    let frame = scene.render(&shaft, 0);
    let row = c[1].floor() as u32;
    let expected =
        p.beam_peak_level[0] * (-2.0 * ((0.5 - c[0]) / p.beam_radius_px[0]).powi(2)).exp();
    assert!((f64::from(frame.pixel(0, row)) - expected).abs() <= 1.0);
    // The visible part decreases monotonically to the right.
    assert!(frame.pixel(0, row) > frame.pixel(100, row));
    assert!(frame.pixel(100, row) > frame.pixel(200, row));
}

#[test]
fn some_default_seeds_start_with_a_beam_off_screen() {
    let p = MichelsonParams::default();
    let off_screen = DEFAULT_SEEDS
        .filter(|&seed| {
            let scene = Michelson::new(p.clone(), michelson_offsets(&p, seed)).unwrap();
            scene.truth(&[0; 4]).beam_centres_px.iter().any(|c| {
                !(0.0..f64::from(p.width_px)).contains(&c[0])
                    || !(0.0..f64::from(p.height_px)).contains(&c[1])
            })
        })
        .count();
    assert!(
        (1..10).contains(&off_screen),
        "{off_screen} of 10 seeds off-screen"
    );
}

#[test]
fn background_and_noise_have_the_configured_statistics() {
    let p = MichelsonParams::default();
    let scene = Michelson::new(p.clone(), [0; 4]).unwrap();
    let frame = scene.render(&[30000, 30000, -30000, -30000], 3);
    let m = mean(&frame, 0, 1920, 0, 1080);
    let var = frame
        .pixels()
        .iter()
        .map(|&v| (f64::from(v) - m).powi(2))
        .sum::<f64>()
        / frame.pixels().len() as f64;
    assert!((m - p.noise.background_level).abs() < 0.05, "mean {m}");
    // Rounding to whole gray levels adds 1/12 to the variance.
    let expected = p.noise.std.powi(2) + 1.0 / 12.0;
    assert!(
        (var / expected - 1.0).abs() < 0.05,
        "variance {var} vs {expected}"
    );
}

#[test]
fn rendering_is_deterministic_per_seed_and_frame_index() {
    let p = MichelsonParams::default();
    let offsets = michelson_offsets(&p, 4);
    let a = Michelson::new(p.clone(), offsets).unwrap();
    let b = Michelson::new(p.clone(), offsets).unwrap();
    let shaft = [100, -200, 300, -400];
    assert_eq!(a.render(&shaft, 7), b.render(&shaft, 7));
    assert_ne!(a.render(&shaft, 7), a.render(&shaft, 8));
    let mut reseeded = p;
    reseeded.noise.seed = 1;
    let c = Michelson::new(reseeded, offsets).unwrap();
    assert_ne!(a.render(&shaft, 7), c.render(&shaft, 7));
}

#[test]
#[should_panic(expected = "Michelson takes 4 axes")]
fn wrong_axis_count_panics() {
    let scene = Michelson::new(MichelsonParams::default(), [0; 4]).unwrap();
    scene.truth(&[0; 3]);
}
