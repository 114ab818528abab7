//! Writes PNGs of each scene's visual regimes into the directory given as the argument.
//!
//! `cargo run -p optalign-optics --example render_regimes -- docs/img`

use std::error::Error;
use std::path::{Path, PathBuf};

use optalign_optics::scenario::{CavityParams, MichelsonParams, RelayParams};
use optalign_optics::seeds::{DEFAULT_SEEDS, cavity_offsets, michelson_offsets, relay_offsets};
use optalign_optics::{CameraPose, Cavity, Frame, Michelson, Relay, Station};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Motor steps (rounded) that move a beam by `d` px through the sensitivity matrix `s`.
fn steps_for(s: [[f64; 2]; 2], d: [f64; 2]) -> [i32; 2] {
    let det = s[0][0] * s[1][1] - s[0][1] * s[1][0];
    [
        ((s[1][1] * d[0] - s[0][1] * d[1]) / det).round() as i32,
        ((-s[1][0] * d[0] + s[0][0] * d[1]) / det).round() as i32,
    ]
}

fn save(dir: &Path, name: &str, frame: &Frame, note: String) -> Result<(), Box<dyn Error>> {
    std::fs::write(dir.join(name), frame.encode_png()?)?;
    println!("{name}: {note}");
    Ok(())
}

fn michelson(dir: &Path) -> Result<(), Box<dyn Error>> {
    let p = MichelsonParams::default();
    let offsets = michelson_offsets(&p, 0);
    let scene = Michelson::new(p.clone(), offsets)?;
    // Shaft that puts beam 1 at d1 and beam 2 at d2 px from the image centre.
    let shaft = |d1: [f64; 2], d2: [f64; 2]| {
        let a = steps_for(p.mirror_1_sensitivity_px_per_step, d1);
        let b = steps_for(p.mirror_2_sensitivity_px_per_step, d2);
        [
            a[0] - offsets[0],
            a[1] - offsets[1],
            b[0] - offsets[2],
            b[1] - offsets[3],
        ]
    };
    let regimes = [
        (
            "michelson_separated.png",
            shaft([-420.0, -120.0], [380.0, 160.0]),
        ),
        (
            "michelson_clipped.png",
            shaft([-940.0, 60.0], [200.0, -500.0]),
        ),
        (
            "michelson_partial_overlap.png",
            shaft([-70.0, -40.0], [80.0, 50.0]),
        ),
        (
            "michelson_centred_fringes.png",
            shaft([0.0, 0.0], [0.0, 0.0]),
        ),
        ("michelson_seed0_start.png", [0; 4]),
    ];
    for (name, s) in regimes {
        let t = scene.truth(&s);
        let note = format!(
            "beams at {:?}, error {:.0} px",
            t.beam_centres_px.map(|c| c.map(|v| v.round())),
            t.error_px
        );
        save(dir, name, &scene.render(&s, 0), note)?;
    }
    Ok(())
}

fn cavity(dir: &Path) -> Result<(), Box<dyn Error>> {
    let p = CavityParams::default();
    let offsets = cavity_offsets(&p, 0);
    let scene = Cavity::new(p, offsets)?;
    let from_aligned = |d: [i32; 2]| [d[0] - offsets[0], d[1] - offsets[1]];
    let regimes = [
        ("cavity_secondary_visible.png", from_aligned([-2000, 1500])),
        ("cavity_near_primary.png", from_aligned([-450, 300])),
        ("cavity_hidden.png", from_aligned([0, 0])),
        ("cavity_artefacts_only.png", from_aligned([30000, 0])),
        ("cavity_seed0_start.png", [0, 0]),
    ];
    for (name, s) in regimes {
        let t = scene.truth(&s);
        let note = format!(
            "secondary at {:?}, error {:.0} steps",
            t.secondary_centre_px.map(|v| v.round()),
            t.error_steps
        );
        save(dir, name, &scene.render(&s, 0), note)?;
    }
    Ok(())
}

/// A shaft that half-clips the beam on M2's edge and steers what passes onto C4.
fn clipped_on_m2(scene: &Relay, aligned: [i32; 8]) -> [i32; 8] {
    let set = |base: [i32; 8], axis: usize, value: i32| {
        let mut s = base;
        s[axis] = value;
        s
    };
    let lateral = |s: &[i32; 8]| {
        scene.truth(s).stations[Station::C4.index()]
            .offset_px
            .map_or(f64::INFINITY, |o| o[0].abs())
    };
    let mut shaft = aligned;
    for _ in 0..3 {
        let base = shaft;
        shaft = (1000..5000)
            .step_by(2)
            .map(|extra| set(base, 1, aligned[1] + extra))
            .find(|s| (0.45..0.55).contains(&scene.truth(s).mirrors[1].transmission))
            .unwrap_or(base);
        let base = shaft;
        shaft = (-8000..8000)
            .step_by(5)
            .map(|extra| set(base, 3, aligned[3] + extra))
            .min_by(|a, b| lateral(a).total_cmp(&lateral(b)))
            .unwrap_or(base);
    }
    shaft
}

fn relay(dir: &Path) -> Result<(), Box<dyn Error>> {
    let p = RelayParams::default();
    let offsets = relay_offsets(&p, 0)?;
    let scene = Relay::new(p.clone(), offsets)?;
    let aligned = offsets.map(|o| -o);
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut slightly_off = aligned;
    slightly_off[1] += 3000;
    slightly_off[0] -= 2000;
    let regimes = [
        ("relay_spot_c8_aligned.png", aligned, Station::C8),
        ("relay_spot_c1_off_centre.png", slightly_off, Station::C1),
        (
            "relay_speckle_c4_clipped.png",
            clipped_on_m2(&scene, aligned),
            Station::C4,
        ),
        ("relay_seed0_start_c1.png", [0; 8], Station::C1),
        ("relay_dark_c8_seed0_start.png", [0; 8], Station::C8),
    ];
    for (name, s, station) in regimes {
        let pose = CameraPose::place(station, &p.camera, &mut rng);
        let t = scene.truth(&s);
        let st = &t.stations[station.index()];
        let transmissions = t.mirrors.map(|m| (m.transmission * 100.0).round() / 100.0);
        let note = format!(
            "{station}: power on sensor {:.2}, offset {:?} px, mirror transmissions {transmissions:?}",
            st.power_on_sensor,
            st.offset_px.map(|o| o.map(|v| v.round()))
        );
        save(dir, name, &scene.render(&s, &pose, 0), note)?;
    }
    Ok(())
}

/// What each default seed starts with (shafts at zero).
fn seed_summary() -> Result<(), Box<dyn Error>> {
    let (m, c, r) = (
        MichelsonParams::default(),
        CavityParams::default(),
        RelayParams::default(),
    );
    let on_screen = |p: [f64; 2], w: u32, h: u32| {
        (0.0..f64::from(w)).contains(&p[0]) && (0.0..f64::from(h)).contains(&p[1])
    };
    for seed in DEFAULT_SEEDS {
        let mt = Michelson::new(m.clone(), michelson_offsets(&m, seed))?.truth(&[0; 4]);
        let beams = mt.beam_centres_px.map(|b| {
            if on_screen(b, m.width_px, m.height_px) {
                "on"
            } else {
                "off"
            }
        });
        let ct = Cavity::new(c.clone(), cavity_offsets(&c, seed))?.truth(&[0; 2]);
        let secondary = if on_screen(ct.secondary_centre_px, c.width_px, c.height_px) {
            "on"
        } else {
            "off"
        };
        let rt = Relay::new(r.clone(), relay_offsets(&r, seed)?)?.truth(&[0; 8]);
        let reached = rt.mirrors.iter().filter(|m| m.reached()).count();
        println!(
            "seed {seed}: michelson beams {beams:?} screen, error {:.0} px | cavity secondary {secondary} screen, {:.0} steps | relay C1 power on sensor {:.2}, mirrors reached {reached}, C8 lit {}",
            mt.error_px, ct.error_steps, rt.stations[0].power_on_sensor, rt.stations[7].lit
        );
    }
    Ok(())
}

fn main() -> Result<(), Box<dyn Error>> {
    let dir: PathBuf = std::env::args_os()
        .nth(1)
        .ok_or("usage: render_regimes <output directory>")?
        .into();
    std::fs::create_dir_all(&dir)?;
    michelson(&dir)?;
    cavity(&dir)?;
    relay(&dir)?;
    seed_summary()
}
