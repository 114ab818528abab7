//! `optalign cameras`: the camera kinds this build reads, and the V4L2 capture devices
//! found, each with the pixel format it would be read in (or why it cannot be).

use clap::Args;

#[derive(Debug, Args)]
pub struct CamerasArgs {}

/// The rig file's `camera.kind` values this build accepts.
pub fn kinds() -> &'static [&'static str] {
    if cfg!(target_os = "linux") {
        &["v4l2", "command", "folder", "http", "sim"]
    } else {
        &["command", "folder", "http", "sim"]
    }
}

pub fn run(_args: CamerasArgs) -> anyhow::Result<()> {
    crate::say!("camera kinds in this build: {}", kinds().join(", "));
    #[cfg(target_os = "linux")]
    list_v4l2()?;
    Ok(())
}

#[cfg(target_os = "linux")]
fn list_v4l2() -> anyhow::Result<()> {
    use crate::lab::camera::{PIXEL_FORMATS, usable_format};
    use linuxvideo::{BufType, CapabilityFlags};

    let mut found = 0;
    for device in linuxvideo::list()? {
        let Ok(device) = device else { continue };
        let Ok(capabilities) = device.capabilities() else {
            continue;
        };
        if !capabilities
            .device_capabilities()
            .contains(CapabilityFlags::VIDEO_CAPTURE)
        {
            continue;
        }
        found += 1;
        let path = device
            .path()
            .map_or("(unknown path)".into(), |p| p.display().to_string());
        let reads = match usable_format(&device) {
            Some((format, full)) => format!(
                "reads {} ({}-bit)",
                String::from_utf8_lossy(&format.as_fourcc()).trim_end(),
                16 - full.leading_zeros()
            ),
            None => {
                let offered: Vec<String> = device
                    .formats(BufType::VIDEO_CAPTURE)
                    .filter_map(Result::ok)
                    .map(|f| String::from_utf8_lossy(&f.pixel_format().as_fourcc()).into_owned())
                    .collect();
                format!(
                    "not usable directly: it offers {} and none of {}; use a command camera",
                    offered.join(", "),
                    PIXEL_FORMATS
                        .iter()
                        .map(|(fourcc, _)| String::from_utf8_lossy(*fourcc).trim_end().to_owned())
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        };
        crate::say!(
            "{path}: {} ({}), {reads}",
            crate::console::escape_controls(capabilities.card()),
            crate::console::escape_controls(capabilities.driver())
        );
    }
    if found == 0 {
        crate::say!("no V4L2 capture device found (/dev/video*)");
    }
    Ok(())
}
