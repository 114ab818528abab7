//! The stability map of one task: a heat map with a row per swept knob value and a column
//! per policy; a cell's colour is the success rate (red 0 .. green 1), its text the
//! successes, the runs, their 95 % interval and the mean terminal error. Harsh values (where the vision agent
//! must hold) are marked with an asterisk.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::{Chart, DrawResult, error_unit};
use crate::bench::results::{PolicyStats, select, success_cell};
use crate::bench::{RunRecord, Setting};
use crate::task::TaskKind;

/// One cell: successes, runs and the mean terminal error over the runs that have one.
struct Cell {
    successes: usize,
    runs: usize,
    error: Option<f64>,
}

pub(crate) struct StabilityMap {
    task: TaskKind,
    policies: Vec<String>,
    /// Row label, whether the value is a harsh one, and one cell per policy.
    rows: Vec<(String, bool, Vec<Cell>)>,
}

const LABEL_WIDTH: i32 = 290;
const CELL_WIDTH: i32 = 200;
const ROW_HEIGHT: i32 = 24;
const TOP: i32 = 78;
const MIN_WIDTH: i32 = 640;
const MIN_HEIGHT: i32 = 320;

impl StabilityMap {
    pub(crate) fn new(
        records: &[RunRecord],
        task: TaskKind,
        policies: &[String],
        settings: &[Setting],
    ) -> Self {
        let rows = settings
            .iter()
            .filter(|s| s.knob.applies_to(task))
            .map(|&setting| {
                let cells = policies
                    .iter()
                    .map(|policy| {
                        let stats = PolicyStats::of(&select(records, task, policy, Some(setting)));
                        Cell {
                            successes: stats.successes,
                            runs: stats.runs,
                            error: stats.terminal_mean,
                        }
                    })
                    .collect();
                let harsh = setting.knob.harsh_values().contains(&setting.value);
                (setting.to_string(), harsh, cells)
            })
            .collect();
        Self {
            task,
            policies: policies.to_vec(),
            rows,
        }
    }
}

/// Red at 0, amber at one half, green at 1.
fn rate_colour(rate: f64) -> RGBColor {
    let lerp = |a: u8, b: u8, t: f64| (f64::from(a) + (f64::from(b) - f64::from(a)) * t) as u8;
    let (low, mid, high) = ((215, 48, 39), (254, 224, 139), (26, 152, 80));
    let (from, to, t): ((u8, u8, u8), (u8, u8, u8), f64) = if rate < 0.5 {
        (low, mid, rate * 2.0)
    } else {
        (mid, high, rate * 2.0 - 1.0)
    };
    RGBColor(
        lerp(from.0, to.0, t),
        lerp(from.1, to.1, t),
        lerp(from.2, to.2, t),
    )
}

fn error_text(error: Option<f64>) -> String {
    match error {
        None => "no error".into(),
        Some(e) if e >= 100.0 => format!("{e:.0}"),
        Some(e) => format!("{e:.1}"),
    }
}

impl Chart for StabilityMap {
    fn size(&self) -> (u32, u32) {
        let width = LABEL_WIDTH + CELL_WIDTH * self.policies.len().max(1) as i32 + 20;
        let height = TOP + ROW_HEIGHT * self.rows.len().max(1) as i32 + 40;
        (width.max(MIN_WIDTH) as u32, height.max(MIN_HEIGHT) as u32)
    }

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
        root.fill(&WHITE)?;
        let title = ("sans-serif", 18).into_font();
        let header = ("sans-serif", 14).into_font();
        let small = ("sans-serif", 12).into_font();
        root.draw(&Text::new(
            format!(
                "{}: stability map (success rate, mean terminal error in {})",
                self.task,
                error_unit(self.task)
            ),
            (10, 10),
            title,
        ))?;
        root.draw(&Text::new(
            "* a harsh value, where the vision agent must hold (at least 90 % of runs)",
            (10, 34),
            small.clone(),
        ))?;
        let centred = Pos::new(HPos::Center, VPos::Center);
        for (i, policy) in self.policies.iter().enumerate() {
            let x = LABEL_WIDTH + CELL_WIDTH * i as i32 + CELL_WIDTH / 2;
            root.draw(&Text::new(
                policy.clone(),
                (x, TOP - 14),
                TextStyle::from(header.clone()).pos(centred),
            ))?;
        }
        for (row, (label, harsh, cells)) in self.rows.iter().enumerate() {
            let y = TOP + ROW_HEIGHT * row as i32;
            let marked = if *harsh {
                format!("{label} *")
            } else {
                label.clone()
            };
            root.draw(&Text::new(
                marked,
                (LABEL_WIDTH - 8, y + ROW_HEIGHT / 2),
                TextStyle::from(small.clone()).pos(Pos::new(HPos::Right, VPos::Center)),
            ))?;
            for (i, cell) in cells.iter().enumerate() {
                let x = LABEL_WIDTH + CELL_WIDTH * i as i32;
                let rate = if cell.runs == 0 {
                    0.0
                } else {
                    cell.successes as f64 / cell.runs as f64
                };
                let fill = if cell.runs == 0 {
                    RGBColor(230, 230, 230)
                } else {
                    rate_colour(rate)
                };
                root.draw(&Rectangle::new(
                    [(x + 1, y + 1), (x + CELL_WIDTH - 1, y + ROW_HEIGHT - 1)],
                    fill.filled(),
                ))?;
                root.draw(&Text::new(
                    format!(
                        "{}  {}",
                        success_cell(cell.successes, cell.runs),
                        error_text(cell.error)
                    ),
                    (x + CELL_WIDTH / 2, y + ROW_HEIGHT / 2),
                    TextStyle::from(small.clone()).pos(centred),
                ))?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colours_run_from_red_through_amber_to_green() {
        assert_eq!(rate_colour(0.0), RGBColor(215, 48, 39));
        assert_eq!(rate_colour(0.5), RGBColor(254, 224, 139));
        assert_eq!(rate_colour(1.0), RGBColor(26, 152, 80));
        assert_eq!(error_text(Some(1234.5)), "1234");
        assert_eq!(error_text(Some(12.34)), "12.3");
        assert_eq!(error_text(None), "no error");
    }
}
