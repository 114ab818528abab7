//! `optalign beams`: the beam detector on an image file, so that a bench's own photographs
//! can be checked before a run trusts them: each beam's centre with its covariance, and how
//! much of the frame is saturated at its own full scale.

use std::path::PathBuf;

use clap::Args;

use crate::imaging::{Picture, find_beams};
use crate::lab::camera::{decode_image, saturated_fraction};

#[derive(Debug, Args)]
pub struct BeamsArgs {
    /// The image: PNG, JPEG or TIFF, 8 or 16 bit (12-bit data in 16-bit words when no value
    /// exceeds 4095), colour taken as luminance.
    image: PathBuf,
    /// Print JSON (the background, the read noise and every beam) instead of a table.
    #[arg(long)]
    json: bool,
}

pub fn run(args: BeamsArgs) -> anyhow::Result<()> {
    let frame = decode_image(&args.image)?;
    let picture = Picture::new(&frame);
    let beams = find_beams(&picture);
    let saturated = saturated_fraction(&frame);
    if args.json {
        let report = serde_json::json!({
            "image": args.image,
            "width": frame.width(),
            "height": frame.height(),
            "full_scale": frame.full_scale(),
            "saturated_share": saturated,
            "background": picture.background(),
            "read_noise": picture.noise(),
            "background_misfit": picture.background_misfit(),
            "beams": beams,
        });
        crate::say!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    crate::say!(
        "{}: {} x {} px, full scale {}, background {:.1} (misfit {:.2}), read noise {:.2} \
         gray levels (of 255), {} beam(s)",
        args.image.display(),
        frame.width(),
        frame.height(),
        frame.full_scale(),
        picture.background(),
        picture.background_misfit(),
        picture.noise(),
        beams.len()
    );
    if saturated > 0.0 {
        let pixels = f64::from(frame.width()) * f64::from(frame.height());
        crate::say!(
            "{:.0} pixel(s) saturated ({:.3}% of the frame, at full scale {})",
            saturated * pixels,
            100.0 * saturated,
            frame.full_scale()
        );
    }
    if !beams.is_empty() {
        crate::say!(
            "{:>3}  {:>17}  {:>26}  {:>15}  {:>6}  {:>7}  notes",
            "#",
            "centre (x, y) px",
            "covariance xx,xy,yy px²",
            "radii px",
            "angle",
            "peak"
        );
    }
    for (i, beam) in beams.iter().enumerate() {
        let [[xx, xy], [_, yy]] = beam.covariance;
        crate::say!(
            "{:>3}  {:>8.2},{:>8.2}  {:>8.2e},{:>8.1e},{:>8.2e}  {:>7.1},{:>7.1}  {:>6.1}  {:>7.1}  {}",
            i + 1,
            beam.centre[0],
            beam.centre[1],
            xx,
            xy,
            yy,
            beam.radii[0],
            beam.radii[1],
            beam.angle_deg,
            beam.peak,
            beam.notes()
        );
    }
    Ok(())
}
