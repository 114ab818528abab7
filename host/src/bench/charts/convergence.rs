//! Convergence: the mean best-so-far error against evaluation with a one-standard-deviation
//! band, per policy (log scale). A run that ended early keeps its last value. For the relay,
//! whose error is undefined while C8 is dark, the chart shows instead the mean number of
//! mirrors aligned (and kept aligned) against evaluation.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawResult, error_unit, grid_mesh, legend, log_range, policy_colour};
use crate::bench::results::{mean, std_dev};
use crate::run::RunSummary;
use crate::task::TaskKind;

struct Series {
    name: String,
    colour: RGBColor,
    mean: Vec<f64>,
    std: Vec<f64>,
}

pub(crate) struct Convergence {
    task: TaskKind,
    budget: usize,
    series: Vec<Series>,
}

/// The value of a run after each evaluation 0..=budget: best-so-far error, or for the
/// relay the number of mirrors aligned by then.
fn trace(run: &RunSummary, budget: usize) -> Option<Vec<f64>> {
    if let Some(milestones) = run.milestones {
        return Some(
            (0..=budget)
                .map(|t| {
                    milestones
                        .iter()
                        .filter(|m| m.is_some_and(|e| e <= t))
                        .count() as f64
                })
                .collect(),
        );
    }
    let mut last = None;
    let values: Vec<f64> = (0..=budget)
        .map(|t| {
            if let Some(Some(value)) = run.best_trace.get(t) {
                last = Some(*value);
            }
            last.unwrap_or(f64::NAN)
        })
        .collect();
    last.map(|_| values)
}

impl Convergence {
    pub(crate) fn new<'a>(
        task: TaskKind,
        policies: &[String],
        runs: &dyn Fn(&str) -> Vec<&'a RunSummary>,
        budget: usize,
    ) -> Self {
        let series = policies
            .iter()
            .enumerate()
            .filter_map(|(i, policy)| {
                let traces: Vec<Vec<f64>> = runs(policy)
                    .iter()
                    .filter_map(|r| trace(r, budget))
                    .collect();
                if traces.is_empty() {
                    return None;
                }
                let column = |t: usize| -> Vec<f64> {
                    traces
                        .iter()
                        .map(|tr| tr[t])
                        .filter(|v| v.is_finite())
                        .collect()
                };
                Some(Series {
                    name: policy.clone(),
                    colour: policy_colour(policy, i),
                    mean: (0..=budget)
                        .map(|t| mean(&column(t)).unwrap_or(f64::NAN))
                        .collect(),
                    std: (0..=budget)
                        .map(|t| std_dev(&column(t)).unwrap_or(0.0))
                        .collect(),
                })
            })
            .collect();
        Self {
            task,
            budget,
            series,
        }
    }

    fn bands(&self, floor: f64) -> Vec<(RGBColor, Vec<(f64, f64)>)> {
        self.series
            .iter()
            .map(|s| {
                let upper = s
                    .mean
                    .iter()
                    .zip(&s.std)
                    .enumerate()
                    .filter(|(_, (m, _))| m.is_finite())
                    .map(|(t, (m, d))| (t as f64, m + d));
                let lower: Vec<(f64, f64)> = s
                    .mean
                    .iter()
                    .zip(&s.std)
                    .enumerate()
                    .filter(|(_, (m, _))| m.is_finite())
                    .map(|(t, (m, d))| (t as f64, (m - d).max(floor)))
                    .collect();
                (s.colour, upper.chain(lower.into_iter().rev()).collect())
            })
            .collect()
    }

    fn lines(&self, floor: f64) -> impl Iterator<Item = (&Series, Vec<(f64, f64)>)> {
        self.series.iter().map(move |s| {
            let points = s
                .mean
                .iter()
                .enumerate()
                .filter(|(_, m)| m.is_finite())
                .map(|(t, m)| (t as f64, m.max(floor)))
                .collect();
            (s, points)
        })
    }
}

impl Chart for Convergence {
    fn size(&self) -> (u32, u32) {
        (800, 450)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let relay = self.task == TaskKind::Relay;
        let title = if relay {
            "relay: mirrors aligned against evaluation (mean ± std)".to_owned()
        } else {
            format!(
                "{}: best-so-far error against evaluation (mean ± std)",
                self.task
            )
        };
        let mut builder = ChartBuilder::on(root);
        builder
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(64);
        let x_range = 0f64..self.budget as f64;
        if relay {
            let mut chart = builder.build_cartesian_2d(x_range, 0f64..4.2)?;
            grid_mesh(&mut chart)
                .y_labels(5)
                .x_desc("evaluation")
                .y_desc("mirrors aligned")
                .label_style(("sans-serif", 13))
                .draw()?;
            for (colour, band) in self.bands(0.0) {
                chart.draw_series(std::iter::once(Polygon::new(
                    band,
                    colour.mix(0.15).filled(),
                )))?;
            }
            for (series, points) in self.lines(0.0) {
                let colour = series.colour;
                chart
                    .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
                    .label(series.name.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                    });
            }
            legend(&mut chart, SeriesLabelPosition::UpperLeft, 13)?;
        } else {
            let (lo, hi) = log_range(self.series.iter().flat_map(|s| {
                s.mean
                    .iter()
                    .zip(&s.std)
                    .map(|(m, d)| m + d)
                    .chain(s.mean.iter().copied())
            }));
            let mut chart = builder.build_cartesian_2d(x_range, (lo..hi).log_scale())?;
            grid_mesh(&mut chart)
                .y_labels(6)
                .x_desc("evaluation")
                .y_desc(format!("best-so-far error ({})", error_unit(self.task)))
                .label_style(("sans-serif", 13))
                .draw()?;
            for (colour, band) in self.bands(lo) {
                chart.draw_series(std::iter::once(Polygon::new(
                    band,
                    colour.mix(0.15).filled(),
                )))?;
            }
            for (series, points) in self.lines(lo) {
                let colour = series.colour;
                chart
                    .draw_series(LineSeries::new(points, colour.stroke_width(2)))?
                    .label(series.name.clone())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                    });
            }
            legend(&mut chart, SeriesLabelPosition::UpperRight, 13)?;
        }
        Ok(())
    }
}
