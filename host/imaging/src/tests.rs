//! The detector on synthetic frames of every beam kind a bench shows, each with its true
//! centre known: round beams must be found within 1 px, all others within 2 px, with
//! stray light, a sloping background, a smear column and hot pixels around them.

use super::synthetic::Scene;
use super::{
    Beam, Picture, changes, find_beams, registered_changes, registered_changes_sized, scene_shift,
};

const W: usize = 640;
const H: usize = 480;

fn beams(scene: &Scene) -> Vec<Beam> {
    find_beams(&Picture::new(&scene.frame()))
}

/// The beam found nearest `truth`, and its distance from it.
fn found(scene: &Scene, truth: [f64; 2]) -> (Beam, f64) {
    let all = beams(scene);
    let distance = |b: &Beam| (b.centre[0] - truth[0]).hypot(b.centre[1] - truth[1]);
    let best = all
        .iter()
        .min_by(|a, b| distance(a).total_cmp(&distance(b)))
        .copied()
        .unwrap_or_else(|| panic!("no beam found near {truth:?}"));
    let d = distance(&best);
    (best, d)
}

/// A plain bench background: dark level, a little slope, read noise.
fn bench(seed: u64) -> Scene {
    Scene::new(W, H)
        .background(8.0, [0.01, -0.006])
        .noise(2.5, seed)
}

#[test]
fn a_round_beam_is_found_to_a_tenth_of_a_pixel() {
    let truth = [321.37, 228.81];
    let (beam, d) = found(&bench(1).gaussian(truth, 45.0, 150.0), truth);
    assert!(d < 0.1, "{d} {beam:?}");
    assert!((beam.size() - 45.0).abs() < 1.5, "{beam:?}");
    assert!(beam.localised && !beam.clipped && !beam.saturated && beam.parts == 1);
}

#[test]
fn a_round_beam_in_heavy_noise_is_found_within_its_uncertainty_and_says_how_sure() {
    let truth = [300.6, 250.2];
    let quiet = found(&bench(2).gaussian(truth, 60.0, 150.0), truth).0;
    let scene = Scene::new(W, H)
        .background(20.0, [0.0, 0.0])
        .gaussian(truth, 60.0, 150.0)
        .noise(60.0, 3);
    let (beam, d) = found(&scene, truth);
    assert!(d < 1.5, "{d} {beam:?}");
    assert!(
        beam.uncertainty > 5.0 * quiet.uncertainty,
        "{beam:?} vs {quiet:?}"
    );
    assert!(
        d < 4.0 * beam.uncertainty,
        "{d} against {}",
        beam.uncertainty
    );
}

#[test]
fn an_elliptical_turned_beam_is_found_and_its_shape_measured() {
    let truth = [280.2, 260.7];
    let (beam, d) = found(
        &bench(4).elliptical(truth, [70.0, 30.0], 35.0, 140.0),
        truth,
    );
    assert!(d < 2.0, "{d} {beam:?}");
    assert!((beam.radii[0] - 70.0).abs() < 4.0 && (beam.radii[1] - 30.0).abs() < 3.0);
    assert!((beam.angle_deg - 35.0).abs() < 3.0, "{beam:?}");
}

#[test]
fn two_lobed_modes_are_one_beam_centred_between_the_lobes() {
    for (m, n) in [(0, 1), (1, 0)] {
        let truth = [330.4, 235.9];
        let (beam, d) = found(&bench(5).hermite_gauss(truth, 50.0, m, n, 150.0), truth);
        assert!(d < 2.0, "TEM{m}{n}: {d} {beam:?}");
        assert_eq!(
            beams(&bench(5).hermite_gauss(truth, 50.0, m, n, 150.0)).len(),
            1
        );
        // In heavy noise the dark line between the lobes splits them into two regions,
        // which are still one beam.
        let noisy = Scene::new(W, H)
            .background(40.0, [0.0, 0.0])
            .hermite_gauss(truth, 50.0, m, n, 150.0)
            .noise(20.0, 6);
        let (beam, d) = found(&noisy, truth);
        assert!(d < 2.0, "TEM{m}{n} in noise: {d} {beam:?}");
        assert_eq!(beams(&noisy).len(), 1, "{beam:?}");
    }
}

#[test]
fn a_doughnut_and_a_flat_top_are_found_at_their_centres() {
    let truth = [310.3, 245.5];
    let (ring, d) = found(&bench(6).donut(truth, 50.0, 150.0), truth);
    assert!(d < 2.0, "{d} {ring:?}");
    let (flat, d) = found(&bench(7).top_hat(truth, 55.0, 120.0), truth);
    assert!(d < 2.0, "{d} {flat:?}");
}

#[test]
fn fringes_and_speckle_inside_a_beam_do_not_move_its_centre() {
    let truth = [305.8, 230.4];
    let etalon = bench(8)
        .gaussian(truth, 70.0, 150.0)
        .etalon(truth, 0.9, 22.0, 60.0);
    let (beam, d) = found(&etalon, truth);
    assert!(d < 2.0, "etalon: {d} {beam:?}");
    let speckled = bench(9).gaussian(truth, 70.0, 120.0).speckle(0.3, 3.0, 11);
    let (beam, d) = found(&speckled, truth);
    assert!(d < 2.0, "speckle: {d} {beam:?}");
    assert!(beam.localised, "a textured spot is still a spot: {beam:?}");
}

#[test]
fn a_saturated_core_keeps_its_centre() {
    let truth = [290.5, 210.3];
    let (beam, d) = found(&bench(10).gaussian(truth, 40.0, 900.0), truth);
    assert!(d < 1.0, "{d} {beam:?}");
    assert!(beam.saturated, "{beam:?}");
}

#[test]
fn saturation_is_the_level_light_piles_up_on_not_a_flat_unsaturated_top() {
    let truth = [290.5, 210.3];
    // A camera that clips at 200, not 255.
    let bright = bench(10).gaussian(truth, 40.0, 900.0).frame();
    let clipped: Vec<u16> = bright.pixels().iter().map(|&p| p.min(200)).collect();
    let frame = optalign_optics::Frame::deep(W as u32, H as u32, clipped, 255).unwrap();
    let beam = find_beams(&Picture::new(&frame))[0];
    assert!(beam.saturated, "{beam:?}");
    // No noise: the top of an unsaturated beam is a flat plateau of one gray level.
    let smooth = Scene::new(W, H).gaussian(truth, 40.0, 150.0);
    let beam = found(&smooth, truth).0;
    assert!(!beam.saturated, "{beam:?}");
}

#[test]
fn a_beam_cut_by_the_border_is_flagged_and_its_fit_finds_the_centre() {
    let truth = [14.0, 230.0];
    let (beam, _) = found(&bench(11).gaussian(truth, 50.0, 150.0), truth);
    assert!(beam.clipped, "{beam:?}");
    assert!(
        beam.centre[0] > truth[0] + 5.0,
        "the centroid is pulled inwards: {beam:?}"
    );
    let fit = beam.fit.expect("a clipped Gaussian beam is fitted");
    let d = (fit.centre[0] - truth[0]).hypot(fit.centre[1] - truth[1]);
    assert!(d < 2.0, "{d} {fit:?}");
}

#[test]
fn diffraction_rings_do_not_pull_the_centre() {
    let truth = [318.2, 244.6];
    let scene = bench(12)
        .gaussian(truth, 30.0, 150.0)
        .rings(truth, 45.0, 25.0);
    let (beam, d) = found(&scene, truth);
    assert!(d < 1.0, "{d} {beam:?}");
}

#[test]
fn stray_light_a_smear_column_and_hot_pixels_leave_the_beam_alone() {
    let truth = [260.4, 300.2];
    let stray = [480.0, 120.0];
    let scene = Scene::new(W, H)
        .background(30.0, [0.05, 0.03])
        .gaussian(truth, 50.0, 140.0)
        .gaussian(stray, 35.0, 90.0)
        .smear_column(250, 20, 25.0)
        .hot_pixels(300, 200.0, 13)
        .noise(3.0, 14);
    let (beam, d) = found(&scene, truth);
    assert!(d < 1.0, "{d} {beam:?}");
    let (ghost, d) = found(&scene, stray);
    assert!(
        d < 1.0,
        "the stray spot is a beam of its own: {d} {ghost:?}"
    );
    assert_eq!(beams(&scene).len(), 2, "{:?}", beams(&scene));
}

#[test]
fn lobes_parted_by_a_faint_node_are_one_beam_and_beams_with_a_faint_valley_stay_apart() {
    // A three-lobed mode whose nodes hold light (a real mode is never perfectly dark
    // there): 10 to 20 % of its lobes' peak, well above the old fixed dark share.
    let truth = [330.4, 235.9];
    let mode = bench(7)
        .hermite_gauss(truth, 55.0, 2, 0, 150.0)
        .gaussian(truth, 45.0, 18.0);
    let found_beams = beams(&mode);
    assert_eq!(found_beams.len(), 1, "{found_beams:?}");
    let (beam, d) = found(&mode, truth);
    assert!(d < 2.0, "{d} {beam:?}");
    // Two separate beams whose valley holds the same share of their peak: their tails add
    // up there, no node, so they stay two.
    let (left, right) = ([245.0, 240.0], [392.0, 240.0]);
    let pair = bench(8)
        .gaussian(left, 60.0, 150.0)
        .gaussian(right, 60.0, 150.0);
    assert_eq!(beams(&pair).len(), 2, "{:?}", beams(&pair));
    assert!(found(&pair, left).1 < 1.5 && found(&pair, right).1 < 1.5);
}

#[test]
fn two_beams_side_by_side_stay_apart() {
    let left = [200.3, 240.0];
    let right = [420.8, 245.0];
    let scene = bench(15)
        .gaussian(left, 65.0, 150.0)
        .gaussian(right, 58.0, 140.0);
    assert_eq!(beams(&scene).len(), 2);
    assert!(found(&scene, left).1 < 1.0 && found(&scene, right).1 < 1.0);
}

#[test]
fn stray_spots_whose_tails_touch_the_beam_stay_apart_from_it() {
    // A relay camera's frame: a broad beam between three stray spots, 2.5 to 2.7 beam radii
    // from it; their tails add up between them (no dark line parts them).
    let beam = [320.0, 237.0];
    let strays = [[517.0, 110.0], [392.0, 410.0], [90.0, 346.0]];
    let scene = strays
        .iter()
        .fold(bench(16).gaussian(beam, 93.0, 220.0), |scene, &at| {
            scene.gaussian(at, 77.0, 175.0)
        });
    assert_eq!(beams(&scene).len(), 4, "{:?}", beams(&scene));
    let (found_beam, off) = found(&scene, beam);
    assert!(off < 1.0, "{found_beam:?} is {off} px off");
    assert_eq!(found_beam.parts, 1);
}

#[test]
fn a_speckle_cloud_is_not_a_spot() {
    let truth = [320.0, 240.0];
    let cloud = bench(16).gaussian(truth, 110.0, 70.0).speckle(1.0, 2.5, 17);
    let (beam, _) = found(&cloud, truth);
    assert!(!beam.localised, "{beam:?}");
}

#[test]
fn a_speckle_cloud_centred_beyond_the_border_is_cut_not_whole() {
    // Its brightest grains stand far above its level: measured against them, the light
    // at the border looked faint and the cloud whole, with a centroid inside the frame.
    let beyond = [506.0, 500.0];
    let cloud = bench(22)
        .gaussian(beyond, 100.0, 120.0)
        .speckle(1.0, 2.5, 23);
    let all = beams(&cloud);
    let strongest = all
        .iter()
        .max_by(|a, b| a.signal.total_cmp(&b.signal))
        .expect("the cloud shows");
    assert!(
        strongest.clipped && strongest.edge_level > 0.5,
        "{strongest:?}"
    );
}

#[test]
fn a_blank_frame_has_no_beams() {
    assert!(beams(&bench(18)).is_empty());
    let busy = Scene::new(W, H)
        .background(60.0, [0.1, 0.05])
        .hot_pixels(500, 150.0, 19)
        .noise(8.0, 20);
    assert!(beams(&busy).is_empty(), "{:?}", beams(&busy));
}

#[test]
fn changes_show_the_moved_beam_through_a_power_drift() {
    let stays = [480.0, 300.0];
    let (from, to) = ([150.0, 150.0], [240.0, 190.0]);
    let before = Scene::new(W, H)
        .background(8.0, [0.0, 0.0])
        .gaussian(stays, 50.0, 140.0)
        .gaussian(from, 40.0, 120.0)
        .noise(2.5, 21);
    // The laser is 10 % brighter in the second frame.
    let after = Scene::new(W, H)
        .background(8.0, [0.0, 0.0])
        .gaussian(stays, 50.0, 154.0)
        .gaussian(to, 40.0, 132.0)
        .noise(2.5, 22);
    let moved = changes(
        &Picture::new(&before.frame()),
        &Picture::new(&after.frame()),
    );
    assert!((moved.gain - 1.1).abs() < 0.02, "{}", moved.gain);
    assert_eq!(moved.appeared.len(), 1, "{:?}", moved.appeared);
    assert_eq!(moved.vanished.len(), 1, "{:?}", moved.vanished);
    let a = moved.appeared[0].centre;
    let v = moved.vanished[0].centre;
    assert!((a[0] - to[0]).hypot(a[1] - to[1]) < 1.5, "{a:?}");
    assert!((v[0] - from[0]).hypot(v[1] - from[1]) < 1.5, "{v:?}");
}

#[test]
fn light_from_the_room_that_rose_between_the_frames_is_not_a_change() {
    // A broad stationary glow and a beam that stays, a beam that moves; between the
    // frames the room light rose by 6 gray levels and sloped a little more. Each picture
    // measures its light above its own background; compared on one background, only the
    // moved beam changed.
    let (stays, from, to) = ([470.0, 320.0], [160.0, 140.0], [250.0, 200.0]);
    let frame = |room: f64, slope: [f64; 2], at: [f64; 2], seed: u64| {
        Scene::new(W, H)
            .background(room, slope)
            .gaussian([320.0, 240.0], 220.0, 60.0)
            .gaussian(stays, 50.0, 140.0)
            .gaussian(at, 35.0, 90.0)
            .noise(2.5, seed)
            .frame()
    };
    let before = Picture::new(&frame(20.0, [0.0, 0.0], from, 41));
    let after = Picture::new(&frame(26.0, [0.01, 0.0], to, 42));
    let moved = changes(&before, &after);
    assert!((moved.gain - 1.0).abs() < 0.02, "{}", moved.gain);
    assert_eq!(moved.appeared.len(), 1, "{:?}", moved.appeared);
    assert_eq!(moved.vanished.len(), 1, "{:?}", moved.vanished);
    let (a, v) = (moved.appeared[0].centre, moved.vanished[0].centre);
    assert!((a[0] - to[0]).hypot(a[1] - to[1]) < 1.5, "{a:?}");
    assert!((v[0] - from[0]).hypot(v[1] - from[1]) < 1.5, "{v:?}");
}

#[test]
fn a_faint_ghost_on_a_bright_beams_halo_does_not_pull_its_core_centre() {
    let truth = [300.3, 240.6];
    // A saturated beam with a broad halo, and a faint ghost on the halo's edge.
    let scene = bench(9)
        .gaussian(truth, 70.0, 1200.0)
        .gaussian(truth, 250.0, 14.0)
        .gaussian([470.0, 140.0], 30.0, 38.0);
    let (beam, _) = found(&scene, truth);
    let core = super::core_centre(&Picture::new(&scene.frame()), &beam, 0.5).unwrap();
    let miss = (core[0] - truth[0]).hypot(core[1] - truth[1]);
    assert!(miss < 0.5, "core centre {core:?}, beam {beam:?}");
}

#[test]
fn heavy_noise_on_a_dark_level_near_black_is_measured_and_the_beam_still_found() {
    // Half the background pixels read 0 at the darkest level: the noise, the background
    // and so the beam's window would all come out wrong if the clipping were ignored.
    let truth = [300.6, 250.2];
    for (std, level) in [(10.0, 6.0), (30.0, 6.0), (60.0, 6.0), (60.0, 20.0)] {
        let scene = Scene::new(W, H)
            .background(level, [0.0, 0.0])
            .gaussian(truth, 40.0, 150.0)
            .noise(std, 3);
        let picture = Picture::new(&scene.frame());
        assert!(
            (picture.noise() - std).abs() < 0.05 * std,
            "noise {std} on level {level} measured as {}",
            picture.noise()
        );
        let (beam, d) = found(&scene, truth);
        assert!(beam.localised, "noise {std}, level {level}: {beam:?}");
        assert!(
            d < 3.0 * beam.uncertainty && d < 3.0,
            "noise {std}, level {level}: {d} px off, uncertainty {}",
            beam.uncertainty
        );
        assert!((beam.size() - 40.0).abs() < 12.0, "{beam:?}");
    }
}

#[test]
fn a_background_sloping_below_black_is_not_taken_for_light() {
    // The black level clips the left half of a steep slope: the background is a hinge, not
    // a plane, and a plane fitted through it would leave a bright wedge that looks like a
    // broad beam.
    let beams_at = [[470.3, 120.6], [250.8, 380.2]];
    let scene = Scene::new(W, H)
        .background(6.0, [0.08, 0.05])
        .gaussian(beams_at[0], 45.0, 140.0)
        .gaussian(beams_at[1], 40.0, 130.0)
        .noise(3.0, 30);
    let all = beams(&scene);
    assert_eq!(all.len(), 2, "{all:?}");
    for truth in beams_at {
        let (beam, d) = found(&scene, truth);
        assert!(d < 1.0 && !beam.clipped, "{d} {beam:?}");
    }
}

/// A cavity-like frame: a saturated primary with a thin ring and a broad halo around
/// `primary`, and a faint spot at `faint`.
fn jittered_bench(primary: [f64; 2], faint: [f64; 2], seed: u64) -> Scene {
    bench(seed)
        .gaussian(primary, 35.0, 1200.0)
        .gaussian(primary, 130.0, 14.0)
        .add(primary, |dx, dy| {
            let d = ((dx * dx + dy * dy).sqrt() - 85.0) / 3.0;
            18.0 * (-d * d).exp()
        })
        .gaussian(faint, 18.0, 40.0)
}

#[test]
fn a_scene_that_jittered_is_registered_and_only_the_faint_spot_that_moved_shows() {
    let primary = [300.0, 240.0];
    let (from, to) = ([480.0, 120.0], [520.0, 170.0]);
    let before = Picture::new(&jittered_bench(primary, from, 31).frame());
    // The primary and its rings moved 3 px right and 2 px up with pointing jitter.
    let after = Picture::new(&jittered_bench([303.0, 238.0], to, 32).frame());
    let primary_beam = *super::nearest(&find_beams(&before), primary).unwrap();
    let shift = scene_shift(&before, &after, &primary_beam, 0.5);
    assert_eq!(shift, [3.0, -2.0]);
    // Unregistered, the primary's edges and rings leave residue as bright as the spot.
    let plain = changes(&before, &after);
    assert!(plain.appeared.len() + plain.vanished.len() > 2, "{plain:?}");
    let moved = registered_changes(&before, &after, shift);
    assert_eq!(moved.appeared.len(), 1, "{:?}", moved.appeared);
    assert_eq!(moved.vanished.len(), 1, "{:?}", moved.vanished);
    let miss = |b: &Beam, p: [f64; 2]| (b.centre[0] - p[0]).hypot(b.centre[1] - p[1]);
    assert!(miss(&moved.appeared[0], to) < 1.5, "{:?}", moved.appeared);
    // Where it vanished is in the earlier picture's own coordinates.
    assert!(miss(&moved.vanished[0], from) < 1.5, "{:?}", moved.vanished);
}

#[test]
fn a_faint_spot_moving_on_the_core_edge_is_not_taken_for_a_move_of_the_scene() {
    let primary = [300.0, 240.0];
    let before = Picture::new(&jittered_bench(primary, [335.0, 230.0], 33).frame());
    let after = Picture::new(&jittered_bench(primary, [320.0, 270.0], 34).frame());
    let primary_beam = *super::nearest(&find_beams(&before), primary).unwrap();
    assert_eq!(scene_shift(&before, &after, &primary_beam, 0.5), [0.0, 0.0]);
}

#[test]
fn a_dim_broad_beam_moving_in_heavy_clipped_noise_is_found_and_the_halo_stays_quiet() {
    // A saturated beam with a broad halo stays put; a dim beam (peak 40 over a dark level
    // of 6, noise 60: half the dark pixels read 0) moves across the halo's edge. At the
    // detector's finest scale it does not stand out of the noise even in the frames'
    // difference; averaged over its own size it does, and nothing else changed.
    let (from, to) = ([470.0, 130.0], [180.0, 370.0]);
    let frame = |dim: [f64; 2], seed: u64| {
        Scene::new(W, H)
            .background(6.0, [0.0, 0.0])
            .gaussian([300.0, 240.0], 70.0, 1200.0)
            .gaussian([300.0, 240.0], 250.0, 14.0)
            .gaussian(dim, 35.0, 40.0)
            .noise(60.0, seed)
            .frame()
    };
    let (before, after) = (Picture::new(&frame(from, 31)), Picture::new(&frame(to, 32)));
    // Where black clips the noise, a dark pixel scatters by less than the noise; on the
    // halo, lifted off black, by more.
    let dark = f64::from(before.noise_map().at(600, 450));
    let halo = f64::from(before.noise_map().at(300, 380));
    assert!((dark / 60.0 - 0.6).abs() < 0.1, "dark scatter {dark}");
    assert!(halo > dark * 1.1, "halo scatter {halo}, dark {dark}");
    let fine = registered_changes(&before, &after, [0.0, 0.0]);
    assert!(
        fine.appeared.is_empty() && fine.vanished.is_empty(),
        "{fine:?}"
    );
    // Looked for at the bright beam's size (all an agent knows before it saw the dim one).
    let moved = registered_changes_sized(&before, &after, [0.0, 0.0], 70.0);
    let off = |b: &Beam, p: [f64; 2]| (b.centre[0] - p[0]).hypot(b.centre[1] - p[1]);
    assert_eq!(moved.appeared.len(), 1, "{:?}", moved.appeared);
    assert_eq!(moved.vanished.len(), 1, "{:?}", moved.vanished);
    let (appeared, vanished) = (moved.appeared[0], moved.vanished[0]);
    // The centre of a spot standing about ten noise deviations out of the difference is
    // good to a few pixels (a seventh of its radius).
    assert!(off(&appeared, to) < 5.0, "{appeared:?}");
    assert!(off(&vanished, from) < 5.0, "{vanished:?}");
    // Its size, from a fit to averages as wide as itself, is good to about half.
    for beam in [appeared, vanished] {
        assert!((beam.size() / 35.0 - 1.0).abs() < 0.6, "{beam:?}");
    }
}

/// The reported uncertainty of the centre of a beam made `frames` times (one scene per
/// seed), mean over the frames, and the centres' root-mean-square distance from `truth`.
fn reported_and_true_scatter(make: impl Fn(u64) -> Scene, truth: [f64; 2]) -> (f64, f64) {
    let frames = 20;
    let (mut reported, mut squares) = (0.0, 0.0);
    for seed in 0..frames {
        let (beam, d) = found(&make(seed), truth);
        reported += beam.uncertainty;
        squares += d * d;
    }
    (reported / frames as f64, (squares / frames as f64).sqrt())
}

#[test]
fn a_beams_uncertainty_covers_what_read_noise_and_speckle_do_to_its_centre() {
    let truth = [321.37, 228.81];
    let clean = reported_and_true_scatter(|s| bench(s).gaussian(truth, 40.0, 150.0), truth);
    assert!(
        clean.0 > 0.7 * clean.1 && clean.0 < 1.5 * clean.1,
        "read noise alone: reported {:.3} px, true scatter {:.3} px",
        clean.0,
        clean.1
    );
    // Speckle on the beam moves its centre far more than read noise does: the reported
    // uncertainty grows with it (grains finer than the beam, a new pattern each frame).
    for (contrast, grain) in [(0.5, 4.0), (0.8, 8.0)] {
        let speckled = reported_and_true_scatter(
            |s| {
                bench(s)
                    .gaussian(truth, 40.0, 150.0)
                    .speckle(contrast, grain, 100 + s)
            },
            truth,
        );
        assert!(
            speckled.1 > 4.0 * clean.1
                && speckled.0 > 0.5 * speckled.1
                && speckled.0 < 2.0 * speckled.1,
            "speckle {contrast} with {grain} px grains: reported {:.3} px, true scatter {:.3} px",
            speckled.0,
            speckled.1
        );
    }
}
