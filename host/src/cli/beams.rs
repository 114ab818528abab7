//! `optalign beams`: the beam detector on an image file, so that a bench's own photographs
//! can be checked before a run trusts them.

use std::path::PathBuf;

use clap::Args;

use crate::imaging::{Beam, Picture, find_beams};
use crate::lab::camera::decode_image;

#[derive(Debug, Args)]
pub struct BeamsArgs {
    /// The image: PNG, JPEG or TIFF, 8 or 16 bit, colour taken as luminance.
    image: PathBuf,
    /// Print JSON (the background, the read noise and every beam) instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn run(args: BeamsArgs) -> anyhow::Result<()> {
    let frame = decode_image(&args.image)?;
    let picture = Picture::new(&frame);
    let beams = find_beams(&picture);
    if args.json {
        let report = serde_json::json!({
            "image": args.image,
            "width": frame.width(),
            "height": frame.height(),
            "background": picture.background(),
            "read_noise": picture.noise(),
            "beams": beams,
        });
        crate::say!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    crate::say!(
        "{}: {} x {} px, background {:.1}, read noise {:.1} gray levels, {} beam(s)",
        args.image.display(),
        frame.width(),
        frame.height(),
        picture.background(),
        picture.noise(),
        beams.len()
    );
    if !beams.is_empty() {
        crate::say!(
            "{:>3}  {:>17}  {:>7}  {:>15}  {:>6}  {:>7}  notes",
            "#",
            "centre (x, y) px",
            "± px",
            "radii px",
            "angle",
            "peak"
        );
    }
    for (i, beam) in beams.iter().enumerate() {
        crate::say!(
            "{:>3}  {:>8.2},{:>8.2}  {:>7.2}  {:>7.1},{:>7.1}  {:>6.1}  {:>7.1}  {}",
            i + 1,
            beam.centre[0],
            beam.centre[1],
            beam.uncertainty,
            beam.radii[0],
            beam.radii[1],
            beam.angle_deg,
            beam.peak,
            notes(beam)
        );
    }
    Ok(())
}

/// What a user should know about a beam before trusting its centre.
fn notes(beam: &Beam) -> String {
    let mut notes = Vec::new();
    if beam.saturated {
        notes.push("saturated".to_string());
    }
    if beam.clipped {
        let fit = beam.fit.map_or(String::new(), |f| {
            format!(", Gaussian fit at {:.1},{:.1}", f.centre[0], f.centre[1])
        });
        notes.push(format!(
            "cut by the border ({:.0}% of peak there{fit})",
            100.0 * beam.edge_level
        ));
    }
    if !beam.localised {
        notes.push("speckle, not a compact spot".to_string());
    }
    if beam.parts > 1 {
        notes.push(format!("{} lobes joined", beam.parts));
    }
    notes.join("; ")
}
