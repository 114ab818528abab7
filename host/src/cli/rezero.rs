//! `optalign rezero`: find the axes whose position was lost (a power cut in the middle of
//! a move) from the camera and the response calibration, and declare them.

use std::path::PathBuf;

use clap::Args;

use crate::lab::rezero::{DEFAULT_SEARCH_RINGS, RezeroSetup, rezero};
use crate::lab::{LabRig, RigFile};

#[derive(Debug, Args)]
pub struct RezeroArgs {
    /// The bench's rig file.
    #[arg(long, value_name = "FILE")]
    rig: PathBuf,
    #[command(flatten)]
    options: RezeroOptions,
}

/// How lost axes are found (shared with `run --rezero`).
#[derive(Debug, Args)]
#[command(next_help_heading = "Finding lost positions (rezero, run --rezero)")]
pub struct RezeroOptions {
    /// The response calibration to read positions through [default: the rig file's
    /// scoring.michelson_calibration, else response-calibration.json beside it].
    #[arg(long, value_name = "FILE")]
    calibration: Option<PathBuf>,
    /// Declare nothing when an axis is known less well than this, steps (one standard
    /// deviation) [default: 5 % of the task's tolerance: for the Michelson of half its
    /// success error through the mirror's response, for the cavity of 500 steps].
    #[arg(long, value_name = "STEPS")]
    max_uncertainty: Option<f64>,
    /// How far to search for a beam out of view: rings of search steps (each moves the
    /// beam by a third of the image's smaller side), 0 to 20.
    #[arg(long, default_value_t = DEFAULT_SEARCH_RINGS, value_parser = clap::value_parser!(i32).range(0..=20))]
    search_rings: i32,
}

impl RezeroOptions {
    /// The setup for `rig`, read from `rig_path`.
    pub fn setup(&self, rig_path: &std::path::Path, rig: &RigFile) -> anyhow::Result<RezeroSetup> {
        RezeroSetup::for_rig(
            rig_path,
            rig,
            self.calibration.clone(),
            self.max_uncertainty,
            self.search_rings,
        )
    }
}

/// Finds and declares the lost axes of the connected `bench`, saying what is done.
pub async fn rezero_bench(bench: &mut LabRig, setup: &RezeroSetup) -> anyhow::Result<()> {
    let declared = rezero(bench, setup, &mut |line| crate::say!("{line}")).await?;
    if !declared.is_empty() {
        crate::say!(
            "re-referenced {} axis(es) through {}",
            declared.len(),
            setup.calibration_path.display()
        );
    }
    Ok(())
}

pub async fn run(args: RezeroArgs) -> anyhow::Result<()> {
    let file = RigFile::load(&args.rig)?;
    let setup = args.options.setup(&args.rig, &file)?;
    let mut bench = LabRig::connect_unscored(file).await?;
    rezero_bench(&mut bench, &setup).await
}
