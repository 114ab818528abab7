//! Scenario parsing: defaults, overrides, unknown fields and invalid values named by path.

use optalign_optics::scenario::{CavityParams, MichelsonParams, RelayParams};
use optalign_optics::{Cavity, Michelson, Relay, Scenario, ScenarioError};

fn invalid(text: &str) -> (String, String) {
    match Scenario::from_toml_str(text) {
        Err(ScenarioError::Invalid { field, reason }) => (field, reason),
        other => panic!("expected an invalid value, got {other:?}"),
    }
}

fn parse_error(text: &str) -> String {
    match Scenario::from_toml_str(text) {
        Err(e @ ScenarioError::Parse(_)) => e.to_string(),
        other => panic!("expected a parse error, got {other:?}"),
    }
}

#[test]
fn empty_text_gives_the_defaults() {
    assert_eq!(Scenario::from_toml_str("").unwrap(), Scenario::default());
    Scenario::default().validate().unwrap();
}

#[test]
fn overrides_keep_the_other_defaults() {
    let s = Scenario::from_toml_str(
        "[michelson]\nwidth_px = 1280\nbeam_radius_px = [90, 80]\n\
         [michelson.noise]\nstd = 0\n\
         [relay]\nmirror_diameter_mm = 50\n\
         [relay.camera]\nplacement_position_std_mm = 0.0\n\
         [[cavity.ghosts]]\ncentre_offset_px = [1, 2]\n",
    )
    .unwrap();
    assert_eq!(s.michelson.width_px, 1280);
    assert_eq!(s.michelson.height_px, 1080);
    assert_eq!(s.michelson.beam_radius_px, [90.0, 80.0]);
    assert_eq!(s.michelson.noise.std, 0.0);
    assert_eq!(s.michelson.noise.background_level, 6.0);
    assert_eq!(s.relay.mirror_diameter_mm, 50.0);
    assert_eq!(s.relay.camera.width_px, 640);
    assert_eq!(s.cavity.ghosts.len(), 1);
    assert_eq!(s.cavity.ghosts[0].centre_offset_px, [1.0, 2.0]);
    assert_eq!(s.cavity.ghosts[0].radius_px, 30.0);
}

#[test]
fn unknown_fields_are_rejected_by_name() {
    let e = parse_error("[relay]\nmirror_diameter = 25.4\n");
    assert!(e.contains("mirror_diameter"), "{e}");
    let e = parse_error("[cavity.secondary]\nbrightness = 3\n");
    assert!(e.contains("brightness"), "{e}");
    let e = parse_error("[mount]\nbacklash = 3\n");
    assert!(e.contains("mount"), "{e}");
}

#[test]
fn invalid_values_name_the_field_and_reason() {
    let err = Scenario::from_toml_str("[relay]\nmirror_diameter_mm = -1\n").unwrap_err();
    assert_eq!(
        err.to_string(),
        "relay.mirror_diameter_mm: must be > 0, got -1"
    );
    let cases = [
        (
            "[michelson]\nbeam_radius_px = [100, 0]",
            "michelson.beam_radius_px[1]",
        ),
        ("[michelson]\nwidth_px = 1", "michelson.width_px"),
        (
            "[michelson]\nmirror_2_sensitivity_px_per_step = [[1, 2], [2, 4]]",
            "michelson.mirror_2_sensitivity_px_per_step",
        ),
        (
            "[michelson]\nvertical_offset_range_steps = -5",
            "michelson.vertical_offset_range_steps",
        ),
        (
            "[michelson.noise]\nsaturation_level = 300",
            "michelson.noise.saturation_level",
        ),
        (
            "[cavity.primary]\nradius_px = 0",
            "cavity.primary.radius_px",
        ),
        (
            "[[cavity.ghosts]]\n[[cavity.ghosts]]\nradius_px = -3",
            "cavity.ghosts[1].radius_px",
        ),
        (
            "[relay]\nstation_distances_mm = [25, 300, 25, 178, 25, 254, 25, 300]",
            "relay.station_distances_mm[1]",
        ),
        (
            "[relay.camera]\nsensor_width_mm = 0",
            "relay.camera.sensor_width_mm",
        ),
        ("[relay.speckle]\ngrain_px = 0.1", "relay.speckle.grain_px"),
    ];
    for (text, field) in cases {
        let (got, reason) = invalid(text);
        assert_eq!(got, field, "{text}");
        assert!(reason.starts_with("must be"), "{reason}");
    }
}

#[test]
fn frames_too_large_to_render_are_refused_before_any_allocation() {
    for table in ["michelson", "cavity", "relay.camera"] {
        let (field, reason) = invalid(&format!("[{table}]\nwidth_px = 16384\nheight_px = 16384"));
        assert_eq!(field, format!("{table}.width_px"));
        assert!(
            reason.contains("268435456 pixels; at most 25000000"),
            "{reason}"
        );
    }
    let (field, _) = invalid("[cavity]\nheight_px = 16385");
    assert_eq!(field, "cavity.height_px");
}

#[test]
fn defaults_round_trip_through_toml() {
    let text = toml::to_string(&Scenario::default()).unwrap();
    assert_eq!(Scenario::from_toml_str(&text).unwrap(), Scenario::default());
}

#[test]
fn scenes_refuse_invalid_parameters() {
    let m = MichelsonParams {
        fringe_period_px: 1.0,
        ..Default::default()
    };
    assert!(Michelson::new(m, [0; 4]).is_err());
    let mut c = CavityParams::default();
    c.secondary.radius_px = f64::NAN;
    assert!(Cavity::new(c, [0; 2]).is_err());
    let r = RelayParams {
        beam_radius_mm: 0.0,
        ..Default::default()
    };
    let err = Relay::new(r, [0; 8]).unwrap_err();
    assert_eq!(err.to_string(), "relay.beam_radius_mm: must be > 0, got 0");
}
