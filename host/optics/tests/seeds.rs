//! Hidden offsets: in range, deterministic, distinct across seeds and scenes, and the relay's
//! redraw rule.

use optalign_optics::scenario::{CavityParams, MichelsonParams, RelayParams};
use optalign_optics::seeds::{
    DEFAULT_SEEDS, MAX_RELAY_DRAWS, SeedError, cavity_offsets, michelson_offsets, relay_offsets,
};

#[test]
fn michelson_offsets_respect_the_axis_ranges() {
    let p = MichelsonParams::default();
    let mut max = [0; 4];
    for seed in 0..500 {
        let o = michelson_offsets(&p, seed);
        for a in 0..4 {
            max[a] = max[a].max(o[a].abs());
        }
    }
    // Horizontal axes (0, 2) reach +-6144, vertical (1, 3) +-4096, and no further.
    assert!(
        max[0] <= 6144 && max[0] > 6000 && max[2] <= 6144 && max[2] > 6000,
        "{max:?}"
    );
    assert!(
        max[1] <= 4096 && max[1] > 4000 && max[3] <= 4096 && max[3] > 4000,
        "{max:?}"
    );
}

#[test]
fn cavity_offsets_respect_the_axis_ranges() {
    let p = CavityParams::default();
    for seed in 0..500 {
        let [x, y] = cavity_offsets(&p, seed);
        assert!(x.abs() <= 6000 && y.abs() <= 3750);
    }
}

#[test]
fn offsets_are_deterministic_and_differ_between_seeds() {
    let m = MichelsonParams::default();
    let c = CavityParams::default();
    let r = RelayParams::default();
    assert_eq!(michelson_offsets(&m, 3), michelson_offsets(&m, 3));
    assert_eq!(cavity_offsets(&c, 3), cavity_offsets(&c, 3));
    assert_eq!(relay_offsets(&r, 3), relay_offsets(&r, 3));
    let all: Vec<[i32; 4]> = DEFAULT_SEEDS.map(|s| michelson_offsets(&m, s)).collect();
    for (i, a) in all.iter().enumerate() {
        assert!(all[i + 1..].iter().all(|b| b != a));
    }
    assert_ne!(cavity_offsets(&c, 1), cavity_offsets(&c, 2));
}

#[test]
fn offset_ranges_come_from_the_scenario() {
    let p = MichelsonParams {
        horizontal_offset_range_steps: 10,
        vertical_offset_range_steps: 0,
        ..Default::default()
    };
    for seed in 0..50 {
        let o = michelson_offsets(&p, seed);
        assert!(o[0].abs() <= 10 && o[2].abs() <= 10 && o[1] == 0 && o[3] == 0);
    }
}

#[test]
fn relay_offsets_stay_in_range() {
    let p = RelayParams::default();
    for seed in DEFAULT_SEEDS {
        let o = relay_offsets(&p, seed).unwrap();
        assert!(o.iter().all(|v| v.abs() <= 10000));
    }
}

#[test]
fn relay_gives_up_when_light_always_reaches_c8() {
    let p = RelayParams {
        offset_range_steps: 0,
        ..Default::default()
    };
    assert_eq!(
        relay_offsets(&p, 0),
        Err(SeedError::RelayNeverDark {
            seed: 0,
            draws: MAX_RELAY_DRAWS
        })
    );
}
