//! `optalign cameras` through the binary: the default build lists the V4L2 camera among the
//! kinds it reads, and says what V4L2 capture devices it found (none is an answer too).

use crate::BIN;

#[test]
fn the_default_build_lists_the_v4l2_camera() {
    let output = std::process::Command::new(BIN)
        .arg("cameras")
        .env("RUST_LOG", "error")
        .output()
        .unwrap();
    let printed = String::from_utf8_lossy(&output.stdout);
    assert!(output.status.success(), "{printed}");
    let kinds = printed
        .lines()
        .find_map(|line| line.strip_prefix("camera kinds in this build: "))
        .unwrap_or_else(|| panic!("no list of kinds: {printed}"));
    assert_eq!(kinds, "v4l2, command, folder, http, sim");
    // Every other line is a device found, or the word that none was.
    let devices: Vec<&str> = printed.lines().skip(1).collect();
    assert!(!devices.is_empty(), "{printed}");
    assert!(
        devices
            .iter()
            .all(|line| line.starts_with("/dev/") || line.starts_with("no V4L2 capture device")),
        "{printed}"
    );
}
