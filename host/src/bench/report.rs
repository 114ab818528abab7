//! The HTML report of a few runs: a results table, each run's error curve, and its frames
//! as a filmstrip of thumbnails with the action taken under each, read back from the
//! run's transcript and frames.

use std::fmt::Write as _;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter};
use std::path::{Path, PathBuf};

use anyhow::Context;
use image::codecs::png::PngEncoder;
use image::{ExtendedColorType, ImageEncoder};
use optalign_optics::Frame;

use super::RunRecord;
use super::charts::{error_unit, write_run_chart};
use crate::run::{RunSummary, StepRecord};

/// Width of filmstrip thumbnails, px.
pub const THUMBNAIL_WIDTH: u32 = 200;

/// Writes a downscaled copy of a frame PNG.
pub fn write_thumbnail(frame_png: &Path, out: &Path, width: u32) -> anyhow::Result<()> {
    let bytes =
        std::fs::read(frame_png).with_context(|| format!("cannot read {}", frame_png.display()))?;
    let frame = Frame::decode_png(&bytes)?;
    let width = width.min(frame.width()).max(1);
    let height =
        ((u64::from(frame.height()) * u64::from(width)) / u64::from(frame.width())).max(1) as u32;
    let image = image::GrayImage::from_raw(frame.width(), frame.height(), frame.to_8bit())
        .context("frame buffer size")?;
    let small = image::imageops::thumbnail(&image, width, height);
    let file = File::create(out).with_context(|| format!("cannot create {}", out.display()))?;
    PngEncoder::new(BufWriter::new(file))
        .write_image(small.as_raw(), width, height, ExtendedColorType::L8)
        .with_context(|| format!("cannot write {}", out.display()))
}

/// The id of a run's section in the report.
fn anchor(summary: &RunSummary) -> String {
    escape(&format!(
        "{}-{}-seed{}",
        summary.task, summary.policy, summary.seed
    ))
}

/// One tile of a filmstrip.
struct Tile {
    image: Option<String>,
    caption: String,
}

/// Reads a run's transcript into filmstrip tiles, writing thumbnails into `thumbs/`.
fn filmstrip(run_dir: &Path, summary: &RunSummary) -> anyhow::Result<Vec<Tile>> {
    let path = run_dir.join("transcript.jsonl");
    let file = File::open(&path).with_context(|| format!("cannot open {}", path.display()))?;
    std::fs::create_dir_all(run_dir.join("thumbs"))?;
    let unit = error_unit(summary.task);
    let describe_error = |error: Option<f64>| {
        error.map_or_else(
            || "no light at C8".to_owned(),
            |e| format!("error {e:.1} {unit}"),
        )
    };
    let mut tiles = Vec::new();
    for line in BufReader::new(file).lines() {
        let line = line?;
        let value: serde_json::Value = serde_json::from_str(&line)
            .with_context(|| format!("malformed line in {}", path.display()))?;
        let (image, caption) = match value.get("type").and_then(|t| t.as_str()) {
            Some("start") => (
                value
                    .get("image")
                    .and_then(|i| i.as_str())
                    .map(str::to_owned),
                format!(
                    "0 · start · {}",
                    describe_error(value.get("error").and_then(|e| e.as_f64()))
                ),
            ),
            Some("step") => {
                let step: StepRecord = serde_json::from_value(value)
                    .with_context(|| format!("malformed step in {}", path.display()))?;
                match &step.rejected {
                    Some(reason) => (
                        None,
                        format!("rejected: {} — {reason}", step.action.describe()),
                    ),
                    None => (
                        step.image.clone(),
                        format!(
                            "{} · {} · {}",
                            step.evaluation,
                            step.action.describe(),
                            describe_error(step.error)
                        ),
                    ),
                }
            }
            _ => continue,
        };
        let thumb = match image {
            Some(frame) => {
                let name = Path::new(&frame)
                    .file_name()
                    .map(|n| n.to_string_lossy().into_owned())
                    .context("frame without a file name")?;
                let relative = format!("thumbs/{name}");
                write_thumbnail(
                    &run_dir.join(&frame),
                    &run_dir.join(&relative),
                    THUMBNAIL_WIDTH,
                )?;
                Some(relative)
            }
            None => None,
        };
        tiles.push(Tile {
            image: thumb,
            caption,
        });
    }
    Ok(tiles)
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// A path relative to the report's folder, with forward slashes.
fn relative(root: &Path, path: &Path) -> String {
    path.strip_prefix(root)
        .unwrap_or(path)
        .components()
        .map(|c| c.as_os_str().to_string_lossy())
        .collect::<Vec<_>>()
        .join("/")
}

const STYLE: &str = "body{font-family:sans-serif;margin:2em;color:#222}\
table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid #bbb;padding:.3em .7em;text-align:left}\
.strip{display:flex;flex-wrap:wrap;gap:8px}figure{margin:0;width:200px;font-size:11px}\
figure img{width:200px;display:block;background:#000}figcaption{margin-top:2px;overflow-wrap:anywhere}\
.ok{color:#087f23}.no{color:#b00020}section{margin-top:2.5em}";

/// Writes `report.html` into `root` for runs whose transcripts and frames lie under it;
/// `charts` (PNG paths under `root`) are shown first. Returns the report's path.
pub fn write_report(
    root: &Path,
    title: &str,
    intro: &str,
    records: &[RunRecord],
    charts: &[PathBuf],
) -> anyhow::Result<PathBuf> {
    let mut html = format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{0}</title><style>{STYLE}</style></head><body>\n<h1>{0}</h1>\n<p>{1}</p>\n",
        escape(title),
        escape(intro)
    );
    html.push_str(
        "<table><tr><th>task</th><th>policy</th><th>seed</th><th>success</th><th>terminal error</th><th>evaluations</th><th>modelled wall-clock (s)</th><th>declared done</th></tr>\n",
    );
    for record in records {
        let s = &record.summary;
        let _ = writeln!(
            html,
            "<tr><td><a href=\"#{}\">{task}</a></td><td>{}</td><td>{}</td><td class=\"{}\">{}</td><td>{}</td><td>{}/{}</td><td>{:.0}</td><td>{}</td></tr>",
            anchor(s),
            escape(&s.policy),
            s.seed,
            if s.success { "ok" } else { "no" },
            if s.success { "yes" } else { "no" },
            s.terminal_error.map_or_else(
                || "no light at C8".to_owned(),
                |e| format!("{e:.1} {}", error_unit(s.task))
            ),
            s.evaluations_used,
            s.budget,
            s.wall_clock_s,
            if s.declared_done { "yes" } else { "no" },
            task = s.task,
        );
    }
    html.push_str("</table>\n");
    for chart in charts
        .iter()
        .filter(|c| c.extension().is_some_and(|e| e == "png"))
    {
        let _ = writeln!(
            html,
            "<img src=\"{}\" alt=\"chart\">",
            escape(&relative(root, chart))
        );
    }
    for record in records {
        let Some(dir) = &record.out_dir else { continue };
        let s = &record.summary;
        write_run_chart(dir, s)?;
        let mut tiles = filmstrip(dir, s)?;
        // A run that kept no frames shows its error curve alone, not a strip of captions.
        if tiles.iter().all(|t| t.image.is_none()) {
            tiles.clear();
        }
        let base = relative(root, dir);
        let _ = writeln!(
            html,
            "<section id=\"{}\"><h2>{task}, {}, seed {}: {} after {} evaluations</h2>\n<p><a href=\"{base}/transcript.jsonl\">transcript</a> · <a href=\"{base}/summary.json\">summary</a>{}</p>\n<img src=\"{base}/error.svg\" alt=\"error curve\" width=\"720\">\n<div class=\"strip\">",
            anchor(s),
            escape(&s.policy),
            s.seed,
            if s.success { "aligned" } else { "not aligned" },
            s.evaluations_used,
            s.failure
                .as_deref()
                .map(|f| format!(" · ended early: {}", escape(f)))
                .unwrap_or_default(),
            task = s.task,
        );
        for tile in &tiles {
            let image = tile.image.as_deref().map_or_else(String::new, |src| {
                format!("<img src=\"{base}/{}\" alt=\"frame\">", escape(src))
            });
            let _ = writeln!(
                html,
                "<figure>{image}<figcaption>{}</figcaption></figure>",
                escape(&tile.caption)
            );
        }
        html.push_str("</div></section>\n");
    }
    html.push_str("</body></html>\n");
    let path = root.join("report.html");
    std::fs::write(&path, html).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(path)
}
