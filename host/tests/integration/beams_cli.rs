//! `optalign beams` on image files a user would bring: a 16-bit PNG of a beam is measured
//! to a tenth of a pixel and reported as JSON; an empty file is a clear error.

use std::process::Command;

use image::{ImageBuffer, Luma};

use crate::BIN;

#[test]
fn a_sixteen_bit_photograph_of_a_beam_is_measured_and_reported_as_json() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("beam.png");
    let truth = [213.4, 141.7];
    let image = ImageBuffer::from_fn(400, 300, |x, y| {
        let (dx, dy) = (x as f64 + 0.5 - truth[0], y as f64 + 0.5 - truth[1]);
        let level = 3000.0 + 40000.0 * (-2.0 * (dx * dx + dy * dy) / (30.0f64 * 30.0)).exp();
        Luma([level as u16])
    });
    image.save(&path).unwrap();

    let output = Command::new(BIN)
        .args(["beams", "--json"])
        .arg(&path)
        .output()
        .unwrap();
    assert!(output.status.success(), "{output:?}");
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let beams = report["beams"].as_array().unwrap();
    assert_eq!(beams.len(), 1, "{report}");
    let centre = &beams[0]["centre"];
    let found = [centre[0].as_f64().unwrap(), centre[1].as_f64().unwrap()];
    assert!(
        (found[0] - truth[0]).hypot(found[1] - truth[1]) < 0.1,
        "{found:?} against {truth:?}"
    );
    assert_eq!(beams[0]["saturated"], false);
    assert!(beams[0]["uncertainty"].as_f64().unwrap() < 0.1);
    assert!((report["background"].as_f64().unwrap() - 3000.0 / 257.0).abs() < 1.0);

    let table = Command::new(BIN).arg("beams").arg(&path).output().unwrap();
    let text = String::from_utf8_lossy(&table.stdout);
    assert!(
        text.contains("1 beam(s)") && text.contains("213."),
        "{text}"
    );
}

#[test]
fn an_empty_image_file_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("empty.png");
    std::fs::write(&path, b"").unwrap();
    let output = Command::new(BIN).arg("beams").arg(&path).output().unwrap();
    assert!(!output.status.success());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("is empty"), "{stderr}");
}
