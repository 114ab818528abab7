//! Charts of a calibration: measured against fitted beam positions for a response scan,
//! and the hysteresis loop with its fitted dead band for a backlash scan.

use std::path::{Path, PathBuf};

use plotters::coord::Shift;
use plotters::prelude::*;

use super::backlash::BacklashReport;
use super::fit::play_operator;
use super::response::ResponsePoint;
use crate::bench::charts::{Chart, DrawResult, save};

struct ResponseChart<'a> {
    mirror: usize,
    points: &'a [ResponsePoint],
}

fn span(values: impl Iterator<Item = f64> + Clone) -> std::ops::Range<f64> {
    let lo = values.clone().fold(f64::INFINITY, f64::min);
    let hi = values.fold(f64::NEG_INFINITY, f64::max);
    let pad = ((hi - lo) * 0.1).max(1.0);
    lo - pad..hi + pad
}

impl Chart for ResponseChart<'_> {
    fn size(&self) -> (u32, u32) {
        (640, 480)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let all = self
            .points
            .iter()
            .flat_map(|p| [p.measured_px, p.fitted_px]);
        let xs = span(all.clone().map(|p| p[0]));
        let ys = span(all.map(|p| p[1]));
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "mirror {} response: measured vs fitted beam centre",
                    self.mirror
                ),
                ("sans-serif", 15),
            )
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(50)
            .build_cartesian_2d(xs, ys.end..ys.start)?;
        chart
            .configure_mesh()
            .x_desc("image x (px)")
            .y_desc("image y (px)")
            .label_style(("sans-serif", 12))
            .draw()?;
        for point in self.points {
            chart.draw_series(LineSeries::new(
                [point.measured_px, point.fitted_px].map(|p| (p[0], p[1])),
                BLACK.mix(0.4),
            ))?;
        }
        chart
            .draw_series(
                self.points
                    .iter()
                    .map(|p| Circle::new((p.measured_px[0], p.measured_px[1]), 4, BLUE.filled())),
            )?
            .label("measured")
            .legend(|(x, y)| Circle::new((x + 8, y), 4, BLUE.filled()));
        chart
            .draw_series(
                self.points
                    .iter()
                    .map(|p| Cross::new((p.fitted_px[0], p.fitted_px[1]), 5, RED.stroke_width(2))),
            )?
            .label("fitted")
            .legend(|(x, y)| Cross::new((x + 8, y), 5, RED.stroke_width(2)));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    }
}

/// Writes `response-mirror<N>.png` and `.svg` in `dir`.
pub fn write_response_chart(
    dir: &Path,
    mirror: usize,
    points: &[ResponsePoint],
) -> anyhow::Result<Vec<PathBuf>> {
    save(
        &ResponseChart { mirror, points },
        dir,
        &format!("response-mirror{mirror}"),
    )
}

struct BacklashChart<'a> {
    axis: &'a str,
    report: &'a BacklashReport,
}

impl Chart for BacklashChart<'_> {
    fn size(&self) -> (u32, u32) {
        (640, 400)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let fit = &self.report.fit;
        let samples = &self.report.samples;
        let commands: Vec<f64> = samples.iter().map(|s| s.0).collect();
        let model: Vec<(f64, f64)> = commands
            .iter()
            .zip(play_operator(&commands, fit.backlash))
            .map(|(c, load)| (*c, fit.offset + fit.gain * load))
            .collect();
        let xs = span(commands.iter().copied());
        let ys = span(samples.iter().map(|s| s.1).chain(model.iter().map(|m| m.1)));
        let mut chart = ChartBuilder::on(root)
            .caption(
                format!(
                    "{}: backlash {:.1} ± {:.1} steps",
                    self.axis, fit.backlash, fit.uncertainty
                ),
                ("sans-serif", 15),
            )
            .margin(10)
            .x_label_area_size(34)
            .y_label_area_size(50)
            .build_cartesian_2d(xs, ys)?;
        chart
            .configure_mesh()
            .x_desc("commanded steps")
            .y_desc("beam position along the motion (px)")
            .label_style(("sans-serif", 12))
            .draw()?;
        chart
            .draw_series(samples.iter().map(|s| Circle::new(*s, 3, BLUE.filled())))?
            .label("measured")
            .legend(|(x, y)| Circle::new((x + 8, y), 3, BLUE.filled()));
        chart
            .draw_series(LineSeries::new(model, RED.stroke_width(2)))?
            .label("linear response with dead band")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], RED.stroke_width(2)));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        Ok(())
    }
}

/// Writes `backlash-<axis>.png` and `.svg` in `dir`.
pub fn write_backlash_chart(
    dir: &Path,
    axis: &str,
    report: &BacklashReport,
) -> anyhow::Result<Vec<PathBuf>> {
    save(
        &BacklashChart { axis, report },
        dir,
        &format!("backlash-{axis}"),
    )
}
