//! Speed against accuracy: one point per run, terminal error (log scale) against
//! evaluations used (left) and modelled wall-clock time (right), one colour per policy,
//! the Pareto front over all runs drawn as a black staircase with its points ringed.
//! Runs that ended without a terminal error (relay: no light at C8) are crosses along the
//! top edge.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawResult, error_unit, grid_mesh, legend, log_range, policy_colour};
use crate::bench::results::pareto_front;
use crate::run::RunSummary;
use crate::task::TaskKind;

struct Series {
    name: String,
    colour: RGBColor,
    /// (evaluations used, modelled wall-clock s, terminal error)
    runs: Vec<(f64, f64, Option<f64>)>,
}

pub(crate) struct SpeedAccuracy {
    task: TaskKind,
    budget: usize,
    series: Vec<Series>,
}

impl SpeedAccuracy {
    pub(crate) fn new<'a>(
        task: TaskKind,
        policies: &[String],
        runs: &dyn Fn(&str) -> Vec<&'a RunSummary>,
        budget: usize,
    ) -> Self {
        let series = policies
            .iter()
            .enumerate()
            .map(|(i, policy)| Series {
                name: policy.clone(),
                colour: policy_colour(policy, i),
                runs: runs(policy)
                    .iter()
                    .map(|r| (r.evaluations_used as f64, r.wall_clock_s, r.terminal_error))
                    .collect(),
            })
            .collect();
        Self {
            task,
            budget,
            series,
        }
    }

    fn panel<DB: DrawingBackend>(
        &self,
        area: &DrawingArea<DB, Shift>,
        wall_clock: bool,
        (y_lo, y_hi): (f64, f64),
    ) -> DrawResult<DB> {
        let x_of = |run: &(f64, f64, Option<f64>)| if wall_clock { run.1 } else { run.0 };
        let x_max = if wall_clock {
            self.series
                .iter()
                .flat_map(|s| s.runs.iter().map(x_of))
                .fold(1.0f64, f64::max)
                * 1.08
        } else {
            self.budget as f64 + 1.0
        };
        let mut chart = ChartBuilder::on(area)
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(64)
            .build_cartesian_2d(0f64..x_max, (y_lo..y_hi).log_scale())?;
        grid_mesh(&mut chart)
            .y_labels(6)
            .x_desc(if wall_clock {
                "modelled wall-clock (s)"
            } else {
                "evaluations used"
            })
            .y_desc(format!("terminal error ({})", error_unit(self.task)))
            .label_style(("sans-serif", 13))
            .draw()?;
        let dark_y = y_hi / 1.5;
        let mut lit: Vec<(f64, f64)> = Vec::new();
        let mut any_dark = false;
        for series in &self.series {
            let colour = series.colour;
            let points: Vec<(f64, f64)> = series
                .runs
                .iter()
                .filter_map(|r| r.2.map(|e| (x_of(r), e.max(y_lo))))
                .collect();
            lit.extend(&points);
            chart
                .draw_series(
                    points
                        .iter()
                        .map(|&p| Circle::new(p, 4, colour.mix(0.85).filled())),
                )?
                .label(series.name.clone())
                .legend(move |(x, y)| Circle::new((x + 8, y), 4, colour.filled()));
            let dark: Vec<(f64, f64)> = series
                .runs
                .iter()
                .filter(|r| r.2.is_none())
                .map(|r| (x_of(r), dark_y))
                .collect();
            any_dark |= !dark.is_empty();
            chart.draw_series(
                dark.into_iter()
                    .map(|p| Cross::new(p, 5, colour.stroke_width(2))),
            )?;
        }
        let front: Vec<(f64, f64)> = pareto_front(&lit).into_iter().map(|i| lit[i]).collect();
        let mut staircase = Vec::with_capacity(front.len() * 2);
        for (i, &(x, y)) in front.iter().enumerate() {
            if i > 0 {
                staircase.push((x, front[i - 1].1));
            }
            staircase.push((x, y));
        }
        if !front.is_empty() {
            chart
                .draw_series(std::iter::once(PathElement::new(
                    staircase,
                    BLACK.stroke_width(1),
                )))?
                .label("Pareto front")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], BLACK.stroke_width(1))
                });
            chart.draw_series(
                front
                    .iter()
                    .map(|&p| Circle::new(p, 7, BLACK.stroke_width(1))),
            )?;
        }
        if any_dark {
            chart.draw_series(std::iter::once(Text::new(
                "× no light at C8",
                (x_max * 0.45, dark_y * 1.25),
                ("sans-serif", 12).into_font(),
            )))?;
        }
        if !wall_clock {
            legend(&mut chart, SeriesLabelPosition::UpperLeft, 13)?;
        }
        Ok(())
    }
}

impl Chart for SpeedAccuracy {
    fn size(&self) -> (u32, u32) {
        (1000, 420)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let root = root.titled(
            &format!("{}: speed against accuracy (one point per run)", self.task),
            ("sans-serif", 18),
        )?;
        let y_range = log_range(
            self.series
                .iter()
                .flat_map(|s| s.runs.iter().filter_map(|r| r.2)),
        );
        let (left, right) = root.split_horizontally(500);
        self.panel(&left, false, y_range)?;
        self.panel(&right, true, y_range)
    }
}
