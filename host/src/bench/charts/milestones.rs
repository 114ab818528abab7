//! Relay milestones: per mirror, the mean evaluation from which it stayed aligned, one bar
//! per policy with a one-standard-deviation whisker, over the runs that reached it; the
//! count reached is written above each bar. Policies that reached none are named in the
//! legend.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawResult, grid_mesh, legend, policy_colour};
use crate::bench::results::{MilestoneStats, PolicyStats};
use crate::run::RunSummary;

struct Series {
    name: String,
    colour: RGBColor,
    runs: usize,
    milestones: [MilestoneStats; 4],
}

pub(crate) struct Milestones {
    budget: usize,
    series: Vec<Series>,
}

impl Milestones {
    pub(crate) fn new<'a>(
        policies: &[String],
        runs: &dyn Fn(&str) -> Vec<&'a RunSummary>,
        budget: usize,
    ) -> Self {
        let series = policies
            .iter()
            .enumerate()
            .filter_map(|(i, policy)| {
                let stats = PolicyStats::of(&runs(policy));
                Some(Series {
                    name: policy.clone(),
                    colour: policy_colour(policy, i),
                    runs: stats.runs,
                    milestones: stats.milestones?,
                })
            })
            .collect();
        Self { budget, series }
    }
}

impl Chart for Milestones {
    fn size(&self) -> (u32, u32) {
        (800, 450)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(
                "relay: evaluations until each mirror stays aligned (mean ± std)",
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(-0.5f64..3.5f64, 0f64..self.budget as f64 * 1.1)?;
        grid_mesh(&mut chart)
            .disable_x_mesh()
            .x_labels(5)
            .x_label_formatter(&|x| {
                let m = x.round();
                if (x - m).abs() < 1e-6 && (0.0..=3.0).contains(&m) {
                    format!("M{}", m as i64 + 1)
                } else {
                    String::new()
                }
            })
            .x_desc("mirror")
            .y_desc("evaluation")
            .label_style(("sans-serif", 13))
            .draw()?;
        let width = 0.8 / self.series.len().max(1) as f64;
        for (k, series) in self.series.iter().enumerate() {
            let colour = series.colour;
            let reached_any = series.milestones.iter().any(|m| m.reached > 0);
            let label = if reached_any {
                series.name.clone()
            } else {
                format!(
                    "{} (no mirror aligned in {} run{})",
                    series.name,
                    series.runs,
                    if series.runs == 1 { "" } else { "s" }
                )
            };
            let bars: Vec<(f64, f64, f64, usize)> = series
                .milestones
                .iter()
                .enumerate()
                .filter_map(|(m, stats)| {
                    let left = m as f64 - 0.4 + k as f64 * width;
                    Some((left, stats.mean?, stats.std.unwrap_or(0.0), stats.reached))
                })
                .collect();
            chart
                .draw_series(bars.iter().map(|&(left, mean, _, _)| {
                    Rectangle::new([(left, 0.0), (left + width * 0.9, mean)], colour.filled())
                }))?
                .label(label)
                .legend(move |(x, y)| {
                    Rectangle::new([(x, y - 5), (x + 12, y + 5)], colour.filled())
                });
            for &(left, mean, std, reached) in &bars {
                let centre = left + width * 0.45;
                chart.draw_series(std::iter::once(PathElement::new(
                    vec![(centre, (mean - std).max(0.0)), (centre, mean + std)],
                    BLACK.stroke_width(1),
                )))?;
                chart.draw_series(std::iter::once(Text::new(
                    format!("{reached}/{}", series.runs),
                    (left, mean + std + self.budget as f64 * 0.06),
                    ("sans-serif", 11).into_font(),
                )))?;
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft, 13)?;
        Ok(())
    }
}
