//! The sweep chart: one row per task, success rate (left) and mean terminal error (right,
//! log scale, over the runs that have one) against the knob's value, one line per policy.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawResult, error_unit, grid_mesh, legend, log_range, policy_colour, tick};
use crate::bench::results::{PolicyStats, select};
use crate::bench::{Knob, RunRecord, Setting};
use crate::task::TaskKind;

struct Series {
    name: String,
    colour: RGBColor,
    /// (knob value, success rate, mean terminal error)
    points: Vec<(f64, f64, Option<f64>)>,
}

pub(crate) struct SweepChart {
    knob: Knob,
    rows: Vec<(TaskKind, Vec<Series>)>,
    x_range: (f64, f64),
}

impl SweepChart {
    pub(crate) fn new(
        records: &[RunRecord],
        tasks: &[TaskKind],
        policies: &[String],
        settings: &[Setting],
    ) -> Self {
        let knob = settings.first().map_or(Knob::Noise, |s| s.knob);
        let rows = tasks
            .iter()
            .map(|&task| {
                let series = policies
                    .iter()
                    .enumerate()
                    .map(|(i, policy)| Series {
                        name: policy.clone(),
                        colour: policy_colour(policy, i),
                        points: {
                            let mut points: Vec<_> = settings
                                .iter()
                                .map(|&setting| {
                                    let stats = PolicyStats::of(&select(
                                        records,
                                        task,
                                        policy,
                                        Some(setting),
                                    ));
                                    (setting.value, stats.success_rate(), stats.terminal_mean)
                                })
                                .collect();
                            points.sort_by(|a, b| a.0.total_cmp(&b.0));
                            points
                        },
                    })
                    .collect();
                (task, series)
            })
            .collect();
        let (lo, hi) = settings
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), s| {
                (lo.min(s.value), hi.max(s.value))
            });
        let pad = if hi > lo { 0.05 * (hi - lo) } else { 0.5 };
        Self {
            knob,
            rows,
            x_range: (lo - pad, hi + pad),
        }
    }

    fn success_panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        task: TaskKind,
        series: &[Series],
    ) -> DrawResult<DB> {
        let mut chart = ChartBuilder::on(area)
            .caption(format!("{task}: success rate"), ("sans-serif", 15))
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(50)
            .build_cartesian_2d(self.x_range.0..self.x_range.1, 0f64..1.05)?;
        let knob = self.knob;
        let value_label = |v: &f64| match knob.value_names() {
            Some(_) => knob.format_value(v.round()),
            None => tick(v),
        };
        grid_mesh(&mut chart)
            .x_desc(self.knob.label())
            .x_label_formatter(&value_label)
            .label_style(("sans-serif", 12))
            .draw()?;
        for s in series {
            let colour = s.colour;
            let points: Vec<(f64, f64)> = s.points.iter().map(|p| (p.0, p.1)).collect();
            chart
                .draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?
                .label(s.name.clone())
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], colour.stroke_width(2))
                });
            chart.draw_series(
                points
                    .into_iter()
                    .map(|p| Circle::new(p, 4, colour.filled())),
            )?;
        }
        legend(&mut chart, SeriesLabelPosition::MiddleRight, 12)?;
        Ok(())
    }

    fn error_panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        task: TaskKind,
        series: &[Series],
    ) -> DrawResult<DB> {
        let (lo, hi) = log_range(
            series
                .iter()
                .flat_map(|s| s.points.iter().filter_map(|p| p.2)),
        );
        let mut chart = ChartBuilder::on(area)
            .caption(
                format!("{task}: terminal error, mean ({})", error_unit(task)),
                ("sans-serif", 15),
            )
            .margin(10)
            .x_label_area_size(36)
            .y_label_area_size(60)
            .build_cartesian_2d(self.x_range.0..self.x_range.1, (lo..hi).log_scale())?;
        let knob = self.knob;
        let value_label = |v: &f64| match knob.value_names() {
            Some(_) => knob.format_value(v.round()),
            None => tick(v),
        };
        grid_mesh(&mut chart)
            .y_labels(6)
            .x_desc(self.knob.label())
            .x_label_formatter(&value_label)
            .label_style(("sans-serif", 12))
            .draw()?;
        if series
            .iter()
            .all(|s| s.points.iter().all(|p| p.2.is_none()))
        {
            chart.draw_series(std::iter::once(Text::new(
                "no run ended with a terminal error (no light at C8)",
                (
                    self.x_range.0 + 0.05 * (self.x_range.1 - self.x_range.0),
                    hi / 2.0,
                ),
                ("sans-serif", 13).into_font(),
            )))?;
        }
        for s in series {
            let colour = s.colour;
            let points: Vec<(f64, f64)> = s
                .points
                .iter()
                .filter_map(|p| p.2.map(|e| (p.0, e.max(lo))))
                .collect();
            chart.draw_series(LineSeries::new(points.clone(), colour.stroke_width(2)))?;
            chart.draw_series(
                points
                    .into_iter()
                    .map(|p| Circle::new(p, 4, colour.filled())),
            )?;
        }
        Ok(())
    }
}

impl Chart for SweepChart {
    fn size(&self) -> (u32, u32) {
        (1000, 60 + 300 * self.rows.len().max(1) as u32)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let root = root.titled(
            &format!("sweep of {}: where each method breaks", self.knob.name()),
            ("sans-serif", 18),
        )?;
        let cells = root.split_evenly((self.rows.len().max(1), 2));
        for ((task, series), pair) in self.rows.iter().zip(cells.chunks(2)) {
            self.success_panel(&pair[0], *task, series)?;
            self.error_panel(&pair[1], *task, series)?;
        }
        Ok(())
    }
}
