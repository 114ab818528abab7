//! What a bench writes besides charts: `results.csv` (one row per run) and `summary.md`
//! (per task, one row per policy: success rate with its 95 % interval, terminal error,
//! evaluations, modelled wall-clock; the relay's milestones; sweep tables), and the
//! statistics behind them.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::Context;

use super::{RunRecord, Setting};
use crate::run::RunSummary;
use crate::scenario::ScenarioFile;
use crate::task::TaskKind;

/// Aggregates of one policy's runs on one task.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyStats {
    pub runs: usize,
    pub successes: usize,
    /// Runs that ended with no terminal error (relay: no light at C8).
    pub dark: usize,
    /// Mean and sample standard deviation of the terminal errors that exist.
    pub terminal_mean: Option<f64>,
    pub terminal_std: Option<f64>,
    pub best_mean: Option<f64>,
    pub median_evaluations: f64,
    pub median_wall_clock_s: f64,
    /// Relay: per mirror, the mean and std of the evaluation from which it stayed aligned
    /// over the runs that reached it, and how many did.
    pub milestones: Option<[MilestoneStats; 4]>,
}

#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct MilestoneStats {
    pub reached: usize,
    pub mean: Option<f64>,
    pub std: Option<f64>,
}

impl PolicyStats {
    pub fn of(runs: &[&RunSummary]) -> Self {
        let terminal: Vec<f64> = runs.iter().filter_map(|r| r.terminal_error).collect();
        let best: Vec<f64> = runs.iter().filter_map(|r| r.best_error).collect();
        let evaluations: Vec<f64> = runs.iter().map(|r| r.evaluations_used as f64).collect();
        let wall: Vec<f64> = runs.iter().map(|r| r.wall_clock_s).collect();
        let milestones = runs.iter().any(|r| r.milestones.is_some()).then(|| {
            std::array::from_fn(|m| {
                let reached: Vec<f64> = runs
                    .iter()
                    .filter_map(|r| r.milestones.and_then(|ms| ms[m]))
                    .map(|e| e as f64)
                    .collect();
                MilestoneStats {
                    reached: reached.len(),
                    mean: mean(&reached),
                    std: std_dev(&reached),
                }
            })
        });
        Self {
            runs: runs.len(),
            successes: runs.iter().filter(|r| r.success).count(),
            dark: runs.iter().filter(|r| r.terminal_error.is_none()).count(),
            terminal_mean: mean(&terminal),
            terminal_std: std_dev(&terminal),
            best_mean: mean(&best),
            median_evaluations: median(&evaluations).unwrap_or(0.0),
            median_wall_clock_s: median(&wall).unwrap_or(0.0),
            milestones,
        }
    }

    pub fn success_rate(&self) -> f64 {
        if self.runs == 0 {
            0.0
        } else {
            self.successes as f64 / self.runs as f64
        }
    }
}

pub fn mean(values: &[f64]) -> Option<f64> {
    (!values.is_empty()).then(|| values.iter().sum::<f64>() / values.len() as f64)
}

/// Sample standard deviation (n - 1); zero for a single value.
pub fn std_dev(values: &[f64]) -> Option<f64> {
    let m = mean(values)?;
    if values.len() < 2 {
        return Some(0.0);
    }
    let ss: f64 = values.iter().map(|v| (v - m).powi(2)).sum();
    Some((ss / (values.len() - 1) as f64).sqrt())
}

pub fn median(values: &[f64]) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    Some(if n % 2 == 1 {
        sorted[n / 2]
    } else {
        0.5 * (sorted[n / 2 - 1] + sorted[n / 2])
    })
}

/// The standard normal quantile at 0.975: a two-sided 95 % interval.
const Z_95: f64 = 1.959_963_984_540_054;

/// The 95 % Wilson score interval of a success rate, `successes` of `runs`; `None` without
/// runs. Unlike the normal approximation it stays within [0, 1] and is not empty at 0/n
/// or n/n (10/10 gives 0.72 to 1: ten seeds cannot tell 100 % from 75 %).
pub fn wilson_interval(successes: usize, runs: usize) -> Option<(f64, f64)> {
    if runs == 0 {
        return None;
    }
    let n = runs as f64;
    let rate = successes.min(runs) as f64 / n;
    let z2 = Z_95 * Z_95;
    let shrink = 1.0 + z2 / n;
    let centre = (rate + z2 / (2.0 * n)) / shrink;
    let half = Z_95 / shrink * (rate * (1.0 - rate) / n + z2 / (4.0 * n * n)).sqrt();
    Some(((centre - half).max(0.0), (centre + half).min(1.0)))
}

/// A success cell as every bench table shows it: `k/n (low–high)`, the 95 % Wilson
/// interval to two decimals.
pub fn success_cell(successes: usize, runs: usize) -> String {
    match wilson_interval(successes, runs) {
        Some((low, high)) => format!("{successes}/{runs} ({low:.2}–{high:.2})"),
        None => format!("{successes}/{runs}"),
    }
}

/// Indices of the points no other point beats on both coordinates (both minimised),
/// ordered by the first coordinate. Of identical points the first is kept.
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..points.len()).collect();
    order.sort_by(|&a, &b| {
        points[a]
            .0
            .total_cmp(&points[b].0)
            .then(points[a].1.total_cmp(&points[b].1))
            .then(a.cmp(&b))
    });
    let mut front = Vec::new();
    let mut lowest = f64::INFINITY;
    for i in order {
        if points[i].1 < lowest {
            lowest = points[i].1;
            front.push(i);
        }
    }
    front
}

/// The runs of `task` and `policy` (and, in a sweep, of one knob value).
pub fn select<'a>(
    records: &'a [RunRecord],
    task: TaskKind,
    policy: &str,
    setting: Option<Setting>,
) -> Vec<&'a RunSummary> {
    records
        .iter()
        .filter(|r| r.summary.task == task && r.summary.policy == policy && r.setting == setting)
        .map(|r| &r.summary)
        .collect()
}

/// Writes one CSV row per run.
pub fn write_csv(path: &Path, records: &[RunRecord]) -> anyhow::Result<()> {
    let mut text = String::from(
        "knob,value,task,policy,seed,success,declared_done,terminal_error,best_error,\
         evaluations_used,budget,rejected_actions,motor_time_s,camera_time_s,agent_time_s,\
         wall_clock_s,milestone_m1,milestone_m2,milestone_m3,milestone_m4,elapsed_s,failure\n",
    );
    let opt = |v: Option<f64>| v.map(|v| format!("{v:.3}")).unwrap_or_default();
    for record in records {
        let s = &record.summary;
        let milestones: Vec<String> = (0..4)
            .map(|m| {
                s.milestones
                    .and_then(|ms| ms[m])
                    .map(|e| e.to_string())
                    .unwrap_or_default()
            })
            .collect();
        let _ = writeln!(
            text,
            "{},{},{},{},{},{},{},{},{},{},{},{},{:.3},{:.3},{:.3},{:.3},{},{},{}",
            record.setting.map(|x| x.knob.name()).unwrap_or_default(),
            record
                .setting
                .map(|x| csv_field(&x.knob.format_value(x.value)))
                .unwrap_or_default(),
            s.task,
            csv_field(&s.policy),
            s.seed,
            s.success,
            s.declared_done,
            opt(s.terminal_error),
            opt(s.best_error),
            s.evaluations_used,
            s.budget,
            s.rejected_actions,
            s.motor_time_s,
            s.camera_time_s,
            s.agent_time_s,
            s.wall_clock_s,
            milestones.join(","),
            opt(record.elapsed_s),
            csv_field(s.failure.as_deref().unwrap_or_default()),
        );
    }
    std::fs::write(path, text).with_context(|| format!("cannot write {}", path.display()))
}

fn csv_field(text: &str) -> String {
    if text.contains([',', '"', '\n']) {
        format!("\"{}\"", text.replace('"', "\"\""))
    } else {
        text.to_owned()
    }
}

/// What the summary's header says about the bench.
#[derive(Clone, Debug)]
pub struct BenchInfo {
    pub tasks: Vec<TaskKind>,
    pub policies: Vec<String>,
    pub seeds: Vec<u64>,
    pub scenario: String,
    pub jobs: usize,
    pub wall_time_s: f64,
}

/// The task's error unit and success rule, for table headings.
fn task_heading(task: TaskKind, scenario: &ScenarioFile) -> String {
    let limits = &scenario.tasks;
    match task {
        TaskKind::Michelson => format!(
            "michelson (budget {}; error in px; success at <= {} px)",
            limits.michelson.budget, limits.michelson.success_error_px
        ),
        TaskKind::Cavity => format!(
            "cavity (budget {}; error in motor steps; success at <= {} steps)",
            limits.cavity.budget, scenario.cavity.success_error_steps
        ),
        TaskKind::Relay => format!(
            "relay (budget {}; error in px from the C8 centre; success: through all four \
             mirrors, centred at C8 within {} px)",
            limits.relay.budget, limits.relay.centred_tolerance_px
        ),
    }
}

fn number(value: Option<f64>) -> String {
    value.map_or_else(|| "–".into(), |v| format!("{v:.1}"))
}

/// The per-task tables of a plain (non-sweep) bench, as Markdown.
pub fn task_tables(
    records: &[RunRecord],
    tasks: &[TaskKind],
    policies: &[String],
    scenario: &ScenarioFile,
) -> String {
    let mut md = String::new();
    for &task in tasks {
        let _ = writeln!(md, "## {}\n", task_heading(task, scenario));
        let relay = task == TaskKind::Relay;
        let _ = writeln!(
            md,
            "| policy | success (95 % interval) | terminal error, mean ± std | best error, mean |{} median evaluations | modelled wall-clock, median (s) |",
            if relay {
                " dark at C8 at the end |"
            } else {
                ""
            }
        );
        let _ = writeln!(
            md,
            "|---|---|---|---|{}---|---|",
            if relay { "---|" } else { "" }
        );
        for policy in policies {
            let stats = PolicyStats::of(&select(records, task, policy, None));
            if stats.runs == 0 {
                continue;
            }
            let terminal = match (stats.terminal_mean, stats.terminal_std) {
                (Some(m), Some(s)) => format!("{m:.1} ± {s:.1}"),
                _ => "–".into(),
            };
            let _ = writeln!(
                md,
                "| {policy} | {} | {terminal} | {} |{} {} | {:.0} |",
                success_cell(stats.successes, stats.runs),
                number(stats.best_mean),
                if relay {
                    format!(" {}/{} |", stats.dark, stats.runs)
                } else {
                    String::new()
                },
                stats.median_evaluations,
                stats.median_wall_clock_s,
            );
        }
        md.push('\n');
        if relay {
            md.push_str(&milestone_table(records, policies));
        }
    }
    md
}

fn milestone_table(records: &[RunRecord], policies: &[String]) -> String {
    let mut md = String::from(
        "Relay milestones: evaluation from which each mirror stayed aligned, mean ± std over \
         the runs that reached it (reached/runs).\n\n| policy | M1 | M2 | M3 | M4 |\n|---|---|---|---|---|\n",
    );
    for policy in policies {
        let stats = PolicyStats::of(&select(records, TaskKind::Relay, policy, None));
        let Some(milestones) = stats.milestones else {
            continue;
        };
        let cells: Vec<String> = milestones
            .iter()
            .map(|m| match (m.mean, m.std) {
                (Some(mean), Some(std)) => {
                    format!("{mean:.1} ± {std:.1} ({}/{})", m.reached, stats.runs)
                }
                _ => format!("– (0/{})", stats.runs),
            })
            .collect();
        let _ = writeln!(md, "| {policy} | {} |", cells.join(" | "));
    }
    md.push('\n');
    md
}

/// The tables of a sweep: per knob and task, success rate and mean terminal error per
/// policy and knob value.
pub fn sweep_tables(
    records: &[RunRecord],
    tasks: &[TaskKind],
    policies: &[String],
    settings: &[Setting],
) -> String {
    let mut md = String::new();
    for knob in knobs_of(settings) {
        let values: Vec<Setting> = settings
            .iter()
            .copied()
            .filter(|s| s.knob == knob)
            .collect();
        for &task in tasks.iter().filter(|t| knob.applies_to(**t)) {
            let _ = writeln!(
                md,
                "## {task}: success rate (95 % interval) and terminal error (mean) against {} ({})\n",
                knob.name(),
                knob.label()
            );
            let header: Vec<String> = values.iter().map(|s| knob.format_value(s.value)).collect();
            let _ = writeln!(md, "| policy | {} |", header.join(" | "));
            let _ = writeln!(md, "|---|{}", "---|".repeat(values.len()));
            for policy in policies {
                let cells: Vec<String> = values
                    .iter()
                    .map(|&setting| {
                        let stats = PolicyStats::of(&select(records, task, policy, Some(setting)));
                        format!(
                            "{}, {}",
                            success_cell(stats.successes, stats.runs),
                            number(stats.terminal_mean)
                        )
                    })
                    .collect();
                let _ = writeln!(md, "| {policy} | {} |", cells.join(" | "));
            }
            md.push('\n');
        }
    }
    md
}

/// The knobs of `settings`, each once, in order.
pub fn knobs_of(settings: &[Setting]) -> Vec<super::Knob> {
    let mut knobs = Vec::new();
    for setting in settings {
        if !knobs.contains(&setting.knob) {
            knobs.push(setting.knob);
        }
    }
    knobs
}

/// Writes `summary.md`: the header, then the task tables (or sweep tables).
pub fn write_summary(
    path: &Path,
    info: &BenchInfo,
    body: &str,
    charts: &[std::path::PathBuf],
) -> anyhow::Result<()> {
    let mut md = String::from("# optalign bench\n\n");
    let seeds = match (info.seeds.first(), info.seeds.last()) {
        (Some(first), Some(last))
            if info.seeds.len() > 1 && info.seeds.windows(2).all(|w| w[1] == w[0] + 1) =>
        {
            format!("{first}..{}", last + 1)
        }
        _ => info
            .seeds
            .iter()
            .map(u64::to_string)
            .collect::<Vec<_>>()
            .join(","),
    };
    let _ = writeln!(
        md,
        "Tasks {}; policies {}; seeds {seeds}; scenario {}. Wall time {:.1} s on {} job(s).\n",
        info.tasks
            .iter()
            .map(|t| t.name())
            .collect::<Vec<_>>()
            .join(", "),
        info.policies.join(", "),
        info.scenario,
        info.wall_time_s,
        info.jobs,
    );
    md.push_str(
        "Terminal error is the error of the final state. Modelled wall-clock adds motor travel \
         at the configured speed and settling, camera moves and frames, and the policy's \
         per-call latency. The baselines spend their last evaluations returning to the best \
         configuration they saw.\n\n",
    );
    md.push_str(body);
    if !charts.is_empty() {
        md.push_str("## Charts\n\n");
        for chart in charts
            .iter()
            .filter(|c| c.extension().is_some_and(|e| e == "png"))
        {
            if let Some(name) = chart.file_name() {
                let name = name.to_string_lossy();
                let _ = writeln!(md, "![{name}](charts/{name})\n");
            }
        }
    }
    std::fs::write(path, md).with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_pareto_front_keeps_exactly_the_undominated_points() {
        let points = [
            (10.0, 5.0),
            (5.0, 9.0),
            (20.0, 1.0),
            (12.0, 6.0), // dominated by (10, 5)
            (5.0, 12.0), // dominated by (5, 9)
            (30.0, 1.0), // dominated by (20, 1)
            (10.0, 5.0), // equal to the first: kept once
            (2.0, 50.0),
        ];
        assert_eq!(pareto_front(&points), vec![7, 1, 0, 2]);
        assert!(pareto_front(&[]).is_empty());
    }

    #[test]
    fn statistics_use_the_sample_deviation_and_the_middle_value() {
        assert_eq!(mean(&[1.0, 2.0, 6.0]), Some(3.0));
        assert_eq!(std_dev(&[2.0, 4.0]), Some(2f64.sqrt()));
        assert_eq!(std_dev(&[7.0]), Some(0.0));
        assert_eq!(median(&[5.0, 1.0, 3.0]), Some(3.0));
        assert_eq!(median(&[4.0, 1.0, 3.0, 10.0]), Some(3.5));
        assert_eq!(median(&[]), None);
    }

    #[test]
    fn wilson_intervals_match_the_published_values() {
        let close = |(low, high): (f64, f64), want: (f64, f64)| {
            assert!(
                (low - want.0).abs() < 5e-5 && (high - want.1).abs() < 5e-5,
                "({low}, {high}) against {want:?}"
            );
        };
        close(wilson_interval(10, 10).unwrap(), (0.7225, 1.0));
        close(wilson_interval(0, 10).unwrap(), (0.0, 0.2775));
        close(wilson_interval(5, 10).unwrap(), (0.2366, 0.7634));
        close(wilson_interval(9, 10).unwrap(), (0.5958, 0.9821));
        close(wilson_interval(30, 30).unwrap(), (0.8865, 1.0));
        close(wilson_interval(97, 100).unwrap(), (0.9155, 0.9897));
        assert_eq!(wilson_interval(0, 0), None);
        let (low, high) = wilson_interval(100, 100).unwrap();
        assert!(high <= 1.0 && (low - 0.9630).abs() < 5e-5, "{low}");
    }

    #[test]
    fn success_cells_carry_their_interval() {
        assert_eq!(success_cell(10, 10), "10/10 (0.72–1.00)");
        assert_eq!(success_cell(0, 10), "0/10 (0.00–0.28)");
        assert_eq!(success_cell(97, 100), "97/100 (0.92–0.99)");
        assert_eq!(success_cell(0, 0), "0/0");
    }

    #[test]
    fn csv_fields_with_commas_or_quotes_are_quoted() {
        assert_eq!(csv_field("plain"), "plain");
        assert_eq!(csv_field("a, \"b\""), "\"a, \"\"b\"\"\"");
    }
}
