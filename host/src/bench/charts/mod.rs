//! Charts of a bench, each written as PNG and SVG: speed against accuracy, best-so-far
//! convergence, relay milestones, sweep curves, the stability map of all swept knobs, and
//! one run's error curve. Text uses the
//! DejaVu Sans font compiled into the binary, so no system font is needed.

mod convergence;
mod milestones;
mod run;
mod speed;
mod stability;
mod sweep;

use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use anyhow::Context;
use image::codecs::png::{CompressionType, FilterType, PngEncoder};
use image::{ExtendedColorType, ImageEncoder};
use plotters::chart::MeshStyle;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use super::{RunRecord, Setting};
use crate::run::RunSummary;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

pub use run::write_run_chart;

/// Result of drawing on a backend.
pub(crate) type DrawResult<DB> =
    Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A chart that can be drawn on any plotters backend.
pub(crate) trait Chart {
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

/// Draws the series legend at `position` in a `font_size` px font, on a light box.
fn legend<'a, DB: DrawingBackend + 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
    font_size: u32,
) -> DrawResult<DB> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.4))
        .label_font(("sans-serif", font_size))
        .draw()
}

/// The mesh every bench chart starts from: its grid styles and plain number labels on
/// both axes; the caller adds the axis descriptions and draws it.
fn grid_mesh<'a, 'b, DB, X, Y>(
    chart: &'b mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
) -> MeshStyle<'a, 'b, X, Y, DB>
where
    DB: DrawingBackend,
    X: Ranged<ValueType = f64> + ValueFormatter<f64>,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let mut mesh = chart.configure_mesh();
    mesh.bold_line_style(BOLD_GRID)
        .light_line_style(LIGHT_GRID)
        .max_light_lines(2)
        .x_label_formatter(&tick)
        .y_label_formatter(&tick);
    mesh
}

/// Registers the bundled font as every family the charts use.
fn fonts() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            for (style, bytes) in [
                (FontStyle::Normal, dejavu::sans::regular()),
                (FontStyle::Bold, dejavu::sans::bold()),
            ] {
                register_font("sans-serif", style, bytes)
                    .map_err(|_| "the bundled DejaVu Sans font did not load".to_owned())?;
            }
            Ok(())
        })
        .clone()
        .map_err(anyhow::Error::msg)
}

/// Writes `stem.svg` and `stem.png` in `dir`; returns both paths.
pub(crate) fn save(chart: &impl Chart, dir: &Path, stem: &str) -> anyhow::Result<Vec<PathBuf>> {
    fonts()?;
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let (width, height) = chart.size();
    let svg = dir.join(format!("{stem}.svg"));
    {
        let root = SVGBackend::new(&svg, (width, height)).into_drawing_area();
        chart
            .draw(&root)
            .and_then(|()| root.present())
            .map_err(|e| anyhow::anyhow!("drawing {}: {e}", svg.display()))?;
    }
    let mut pixels = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        chart
            .draw(&root)
            .and_then(|()| root.present())
            .map_err(|e| anyhow::anyhow!("drawing {stem}.png: {e}"))?;
    }
    let png = dir.join(format!("{stem}.png"));
    let file =
        std::fs::File::create(&png).with_context(|| format!("cannot create {}", png.display()))?;
    PngEncoder::new_with_quality(
        BufWriter::new(file),
        CompressionType::Best,
        FilterType::Adaptive,
    )
    .write_image(&pixels, width, height, ExtendedColorType::Rgb8)
    .with_context(|| format!("cannot write {}", png.display()))?;
    Ok(vec![png, svg])
}

/// The colour of a policy on every chart: fixed for the known policies, otherwise one of
/// the two colours they leave free, by position (colour-blind-safe palette).
pub fn policy_colour(policy: &str, index: usize) -> RGBColor {
    const PALETTE: [RGBColor; 6] = [
        RGBColor(0, 114, 178),
        RGBColor(230, 159, 0),
        RGBColor(0, 158, 115),
        RGBColor(204, 121, 167),
        RGBColor(86, 180, 233),
        RGBColor(213, 94, 0),
    ];
    match policy {
        "bo" => PALETTE[0],
        "random" => PALETTE[1],
        "vision" => PALETTE[2],
        "vlm" => PALETTE[3],
        _ => PALETTE[4 + index % 2],
    }
}

/// The unit of a task's error.
pub fn error_unit(task: TaskKind) -> &'static str {
    match task {
        TaskKind::Michelson => "px",
        TaskKind::Cavity => "motor steps",
        TaskKind::Relay => "px from the C8 centre",
    }
}

/// Grid line colours of every chart.
const BOLD_GRID: RGBColor = RGBColor(205, 205, 205);
const LIGHT_GRID: RGBColor = RGBColor(240, 240, 240);

/// An axis label without needless decimals: 1500, 40, 2.5, 0.25.
fn tick(value: &f64) -> String {
    if value.abs() >= 10.0 {
        return format!("{value:.0}");
    }
    let text = format!("{value:.2}");
    let text = text.trim_end_matches('0').trim_end_matches('.');
    if text == "-0" {
        "0".into()
    } else {
        text.into()
    }
}

/// A log-scale range that holds every positive value (with room above and below); zeros
/// sit on its floor.
pub(crate) fn log_range(values: impl IntoIterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
            (if v > 0.0 { lo.min(v) } else { lo }, hi.max(v))
        });
    if !lo.is_finite() || hi <= 0.0 {
        return (1.0, 1000.0);
    }
    let lo = lo.max(hi * 1e-4).max(1e-3);
    (lo / 2.0, hi * 2.0)
}

/// Writes the charts of a plain bench into `dir`: per task speed against accuracy and
/// convergence, and the relay milestones when the relay ran. Returns the files written.
pub fn write_bench_charts(
    dir: &Path,
    records: &[RunRecord],
    tasks: &[TaskKind],
    policies: &[String],
    scenario: &ScenarioFile,
) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for &task in tasks {
        let runs = |policy: &str| -> Vec<&RunSummary> {
            super::results::select(records, task, policy, None)
        };
        let budget = scenario.tasks.budget(task);
        let speed = speed::SpeedAccuracy::new(task, policies, &runs, budget);
        written.extend(save(&speed, dir, &format!("speed_accuracy_{task}"))?);
        let convergence = convergence::Convergence::new(task, policies, &runs, budget);
        written.extend(save(&convergence, dir, &format!("convergence_{task}"))?);
        if task == TaskKind::Relay {
            let chart = milestones::Milestones::new(policies, &runs, budget);
            written.extend(save(&chart, dir, "relay_milestones")?);
        }
    }
    Ok(written)
}

/// Writes the charts of a sweep into `dir`: per knob, success rate and terminal error
/// against its value (per task and policy); per task, the stability map of every knob
/// value and policy. Returns the files written.
pub fn write_sweep_charts(
    dir: &Path,
    records: &[RunRecord],
    tasks: &[TaskKind],
    policies: &[String],
    settings: &[Setting],
) -> anyhow::Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    for knob in super::results::knobs_of(settings) {
        let values: Vec<Setting> = settings
            .iter()
            .copied()
            .filter(|s| s.knob == knob)
            .collect();
        let swept: Vec<TaskKind> = tasks
            .iter()
            .copied()
            .filter(|t| knob.applies_to(*t))
            .collect();
        let chart = sweep::SweepChart::new(records, &swept, policies, &values);
        written.extend(save(&chart, dir, &format!("sweep_{}", knob.name()))?);
    }
    for &task in tasks {
        let map = stability::StabilityMap::new(records, task, policies, settings);
        written.extend(save(&map, dir, &format!("stability_{task}"))?);
    }
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_drop_needless_decimals() {
        let labels: Vec<String> = [1500.0, 40.0, 2.5, 1.0, 0.9, 0.25, 0.0, -0.001]
            .iter()
            .map(tick)
            .collect();
        assert_eq!(labels, ["1500", "40", "2.5", "1", "0.9", "0.25", "0", "0"]);
    }

    #[test]
    fn log_ranges_hold_every_value_and_survive_empty_input() {
        assert_eq!(log_range([]), (1.0, 1000.0));
        assert_eq!(log_range([0.0, f64::NAN]), (1.0, 1000.0));
        assert_eq!(log_range([3.0, 800.0, 0.0]), (1.5, 1600.0));
        assert_eq!(
            log_range([1e-9, 10.0]).0,
            0.0005,
            "at most four decades below the top"
        );
    }
}
