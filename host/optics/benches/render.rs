//! Frame rendering time of each scene in its characteristic regimes (budget: 10 ms a frame).

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use optalign_optics::scenario::{CavityParams, MichelsonParams, RelayParams};
use optalign_optics::{CameraPose, Cavity, Michelson, Relay, Station};

fn michelson(c: &mut Criterion) {
    let offsets = [1200, -800, -2000, 1500];
    let scene = Michelson::new(MichelsonParams::default(), offsets).unwrap();
    let aligned = offsets.map(|o| -o);
    let separated = [aligned[0] - 1500, aligned[1], aligned[2] - 1500, aligned[3]];
    let off_screen = [20000, 20000, -20000, -20000];
    let mut frame = 0;
    let mut bench = |name: &str, shaft: [i32; 4]| {
        c.bench_function(name, |b| {
            b.iter(|| {
                frame += 1;
                scene.render(black_box(&shaft), frame)
            })
        });
    };
    bench("michelson 1920x1080 centred fringes", aligned);
    bench("michelson 1920x1080 separated", separated);
    bench("michelson 1920x1080 both off-screen", off_screen);
}

fn cavity(c: &mut Criterion) {
    let offsets = [2500, -1500];
    let scene = Cavity::new(CavityParams::default(), offsets).unwrap();
    let shaft = [-offsets[0] + 2000, -offsets[1] - 1000];
    let mut frame = 0;
    c.bench_function("cavity 1280x1024 secondary visible", |b| {
        b.iter(|| {
            frame += 1;
            scene.render(black_box(&shaft), frame)
        })
    });
}

/// A shaft that clips about half the beam on M2's edge and steers what passes onto C4.
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
            .expect("some tilt half-clips the beam on M2");
        let base = shaft;
        shaft = (-8000..8000)
            .step_by(5)
            .map(|extra| set(base, 3, aligned[3] + extra))
            .min_by(|a, b| lateral(a).total_cmp(&lateral(b)))
            .expect("non-empty scan");
    }
    shaft
}

fn relay(c: &mut Criterion) {
    let offsets = [3000, -4000, 2500, 1000, -500, 7000, 1500, -2500];
    let scene = Relay::new(RelayParams::default(), offsets).unwrap();
    let aligned = offsets.map(|o| -o);
    let clipped = clipped_on_m2(&scene, aligned);
    let mut frame = 0;
    let mut bench = |name: &str, shaft: [i32; 8], station: Station| {
        let pose = CameraPose::nominal(station);
        c.bench_function(name, |b| {
            b.iter(|| {
                frame += 1;
                scene.render(black_box(&shaft), &pose, frame)
            })
        });
    };
    bench("relay 640x480 spot at C8", aligned, Station::C8);
    bench("relay 640x480 speckle at C4", clipped, Station::C4);
    bench("relay 640x480 dark at C8", [0; 8], Station::C8);
}

/// One-off costs when a scene is built (the cavity's stationary layer, the relay's speckle
/// tile); the shared noise table is built before timing starts.
fn construction(c: &mut Criterion) {
    c.bench_function("cavity new", |b| {
        b.iter(|| Cavity::new(CavityParams::default(), black_box([100, 200])).unwrap())
    });
    c.bench_function("relay new", |b| {
        b.iter(|| Relay::new(RelayParams::default(), black_box([0; 8])).unwrap())
    });
}

criterion_group!(benches, michelson, cavity, relay, construction);
criterion_main!(benches);
