//! Speed of beam finding on simulated frames: the picture (background, noise, streaks, hot
//! pixels), the beams in it, and the changes between two frames.

use criterion::{Criterion, criterion_group, criterion_main};
use optalign::imaging::{Picture, changes, find_beams};
use optalign::scenario::ScenarioFile;
use optalign_optics::{Cavity, Michelson};

fn detector(c: &mut Criterion) {
    let scenario = ScenarioFile::default();
    let michelson = Michelson::new(scenario.michelson.clone(), [0; 4]).unwrap();
    let apart = michelson.render(&[-2500, 600, 2600, -500], 1);
    let moved = michelson.render(&[-2000, 600, 2600, -500], 2);
    let cavity = Cavity::new(scenario.cavity.clone(), [0; 2]).unwrap();
    let cavity_frame = cavity.render(&[2000, 1500], 1);

    c.bench_function("picture, Michelson 1920x1080", |b| {
        b.iter(|| Picture::new(&apart))
    });
    let picture = Picture::new(&apart);
    c.bench_function("find_beams, Michelson two beams", |b| {
        b.iter(|| find_beams(&picture))
    });
    let after = Picture::new(&moved);
    c.bench_function("changes, Michelson one beam moved", |b| {
        b.iter(|| changes(&picture, &after))
    });
    c.bench_function("picture + find_beams, cavity 1280x1024", |b| {
        b.iter(|| find_beams(&Picture::new(&cavity_frame)))
    });
}

criterion_group!(benches, detector);
criterion_main!(benches);
