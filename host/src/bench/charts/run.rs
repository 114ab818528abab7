//! One run's error curve: the error after each evaluation (dots, where defined) and the
//! best so far (line), log scale; for the relay, dashed verticals mark the mirror
//! milestones.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawResult, error_unit, grid_mesh, legend, log_range, policy_colour, save};
use crate::run::RunSummary;

struct RunChart<'a> {
    run: &'a RunSummary,
}

impl Chart for RunChart<'_> {
    fn size(&self) -> (u32, u32) {
        (720, 300)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let run = self.run;
        let colour = policy_colour(&run.policy, 0);
        let (lo, hi) = log_range(run.error_trace.iter().flatten().copied());
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "{} with {}, seed {}: error per evaluation",
                    run.task, run.policy, run.seed
                ),
                ("sans-serif", 15),
            )
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..run.budget.max(1) as f64, (lo..hi).log_scale())?;
        grid_mesh(&mut chart)
            .y_labels(6)
            .x_desc("evaluation")
            .y_desc(format!("error ({})", error_unit(run.task)))
            .label_style(("sans-serif", 12))
            .draw()?;
        let errors: Vec<(f64, f64)> = run
            .error_trace
            .iter()
            .enumerate()
            .filter_map(|(t, e)| e.map(|e| (t as f64, e.max(lo))))
            .collect();
        let best: Vec<(f64, f64)> = run
            .best_trace
            .iter()
            .enumerate()
            .filter_map(|(t, e)| e.map(|e| (t as f64, e.max(lo))))
            .collect();
        chart
            .draw_series(
                errors
                    .into_iter()
                    .map(|p| Circle::new(p, 3, colour.mix(0.6).filled())),
            )?
            .label("error")
            .legend(move |(x, y)| Circle::new((x + 8, y), 3, colour.filled()));
        chart
            .draw_series(LineSeries::new(best, colour.stroke_width(2)))?
            .label("best so far")
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
            });
        if let Some(milestones) = run.milestones {
            for (m, evaluation) in milestones.iter().enumerate() {
                let Some(evaluation) = evaluation else {
                    continue;
                };
                let x = *evaluation as f64;
                chart.draw_series(DashedLineSeries::new(
                    vec![(x, lo), (x, hi)],
                    4,
                    4,
                    BLACK.mix(0.5).stroke_width(1),
                ))?;
                chart.draw_series(std::iter::once(Text::new(
                    format!("M{}", m + 1),
                    (x + 0.5, hi / 1.3),
                    ("sans-serif", 11).into_font(),
                )))?;
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperRight, 12)?;
        Ok(())
    }
}

/// Writes `error.png` and `error.svg` for one run into `dir`.
pub fn write_run_chart(dir: &Path, run: &RunSummary) -> anyhow::Result<Vec<PathBuf>> {
    save(&RunChart { run }, dir, "error")
}
