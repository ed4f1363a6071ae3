//! The Table-I report: the measured cells collected from the evaluations, checked against the
//! paper's claims, written as Markdown, CSV and a PNG chart with the run's command, date and
//! machine.

use std::fs;
use std::path::Path;
use std::process::Command;

use segmenter_bridge::Bridge;
use serde::Serialize;
use serde_json::Value;

use super::plan::Row;
use super::table::{METHODS, Method, PAPER, QUICK_SIZES, SIZES, TASKS};
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::seeds::{SEEDS, first_heldout_seed};

/// "a vs b" with two decimals, or as many more (up to four) as it takes for two different
/// values not to read as a tie.
fn versus(a: f64, b: f64) -> String {
    let digits = (2..=4).find(|&d| format!("{a:.d$}") != format!("{b:.d$}")).unwrap_or(4);
    format!("{a:.digits$} vs {b:.digits$}")
}


/// One cell of the table, measured.
#[derive(Debug, Clone, Serialize)]
pub(super) struct Cell {
    method: &'static str,
    model_type: &'static str,
    task: String,
    demos: u64,
    episodes: u64,
    success_rate: f64,
    med_cm: f64,
    latency_ms_p50: f64,
    train_seconds: f64,
    eval_seconds: f64,
    parameters: u64,
}

pub(super) fn read_json(path: &Path) -> Result<Value, Failure> {
    let text = fs::read_to_string(path).map_err(|err| Failure::Environment(format!("cannot read {}: {err}", path.display())))?;
    serde_json::from_str(&text).map_err(|err| Failure::Environment(format!("{} is not JSON: {err}", path.display())))
}

/// The measured cells, from each row's evaluation JSON and training report.
pub(super) fn collect_results(rows: &[Row], episodes: u64) -> Result<Vec<Cell>, Failure> {
    let number = |value: &Value, key: &str| value.get(key).and_then(Value::as_f64).unwrap_or(f64::NAN);
    rows.iter()
        .map(|row| {
            let evaluation = read_json(&row.evaluation)?;
            // A model reused from an earlier run without its report still has a card; its
            // training time is then unknown here.
            let training = read_json(&row.training).unwrap_or(Value::Null);
            Ok(Cell {
                method: row.method.label,
                model_type: row.method.model_type,
                task: row.task.to_owned(),
                demos: training.get("demos").and_then(Value::as_u64).unwrap_or(0),
                episodes,
                success_rate: number(&evaluation, "success_rate"),
                med_cm: number(&evaluation, "med_cm"),
                latency_ms_p50: number(&evaluation, "latency_ms_p50"),
                train_seconds: number(&training, "seconds"),
                eval_seconds: number(&evaluation, "wall_time_s"),
                parameters: training.get("parameters").and_then(Value::as_u64).unwrap_or(0),
            })
        })
        .collect()
}

pub(super) struct Report {
    pub command: String,
    pub quick: bool,
    pub episodes: u64,
    pub jobs: usize,
    pub reused: usize,
    pub total_jobs: usize,
    pub wall_time_s: f64,
    pub machine: String,
    pub date: String,
    pub results: Vec<Cell>,
}

impl Report {
    fn cell(&self, method: &Method, task: &str) -> Option<&Cell> {
        self.results.iter().find(|c| c.method == method.label && c.task == task)
    }

    /// MED / success per method and task, in the paper's layout.
    pub(super) fn markdown_table(&self) -> String {
        let mut out = String::from("| method | wall avoidance | incline pick-place | cup stacking | cube stacking |\n|---|---|---|---|---|\n");
        for method in &METHODS {
            let cells: Vec<String> = TASKS
                .iter()
                .map(|task| self.cell(method, task).map_or("n/a".into(), |c| format!("{:.2} / {:.2}", c.med_cm, c.success_rate)))
                .collect();
            out += &format!("| {} | {} |\n", method.label, cells.join(" | "));
        }
        out
    }

    fn paper_table(&self) -> String {
        let mut out = String::from("| method | wall avoidance | incline pick-place | cup stacking | cube stacking |\n|---|---|---|---|---|\n");
        for (method, paper) in METHODS.iter().zip(PAPER) {
            let cells: Vec<String> = paper.iter().map(|c| c.map_or("n/a".into(), |(med, s)| format!("{med:.2} / {s:.2}"))).collect();
            out += &format!("| {} | {} |\n", method.label, cells.join(" | "));
        }
        out
    }

    /// The claims, each checked on the measured table.
    fn claims(&self) -> Vec<(String, bool)> {
        let [cnn_low, cnn_high, _, nogate, ours] = &METHODS;
        let mut claims = Vec::new();
        for task in TASKS {
            let get = |m: &Method| self.cell(m, task).map_or((f64::NAN, f64::NAN), |c| (c.med_cm, c.success_rate));
            let ((ours_med, ours_success), (low_med, low_success), (high_med, _)) = (get(ours), get(cnn_low), get(cnn_high));
            claims.push((
                format!("{task}: ours (low) beats CNN-CNMP (low) on MED ({} cm) and success ({ours_success:.2} vs {low_success:.2})", versus(ours_med, low_med)),
                ours_med < low_med && ours_success > low_success,
            ));
            claims.push((format!("{task}: ours (low) beats CNN-CNMP (high) on MED ({} cm)", versus(ours_med, high_med)), ours_med < high_med));
            if matches!(task, "cup_stacking" | "cube_stacking") {
                let (nogate_med, nogate_success) = get(nogate);
                claims.push((
                    format!("{task}: ours beats ours without gating (MED {} cm, success {ours_success:.2} vs {nogate_success:.2})", versus(ours_med, nogate_med)),
                    ours_med < nogate_med && ours_success >= nogate_success,
                ));
            }
        }
        claims
    }

    fn markdown(&self) -> String {
        let grid = &SEEDS.nfmp_grid.seeds;
        let mut out = format!(
            "# Table I on the cnfmp benchmark{}\n\nMED (cm) / success rate on the same {} held-out scenes per task (seeds {}..={}), every method trained on the same demonstrations (training seeds from {}; low / high regime: {}; NFMP on the {}-scene {} grid, training seeds {}..={}). Each model is one training run, seeded 0 unless its recipe (configs/core) names the seed of the shipped model.\n\n",
            if self.quick { " (--quick: tiny sizes and steps; the numbers mean nothing)" } else { "" },
            self.episodes,
            first_heldout_seed(),
            first_heldout_seed() + self.episodes - 1,
            SEEDS.training.start,
            if self.quick {
                format!("{} / {} demonstrations for every task", QUICK_SIZES.0, QUICK_SIZES.1)
            } else {
                TASKS.iter().zip(SIZES).map(|(t, (l, h))| format!("{t} {l} / {h}")).collect::<Vec<_>>().join(", ")
            },
            grid.end - grid.start,
            SEEDS.nfmp_grid.task,
            grid.start,
            grid.end - 1,
        );
        out += &self.markdown_table();
        out += "\n![Table I](table1.png)\n\n## The claims, checked\n\n";
        for (claim, holds) in self.claims() {
            out += &format!("- {} {claim}\n", if holds { "yes:" } else { "**no**:" });
        }
        out += "\nWhere a claim fails it is reported as measured: nothing was tuned on the held-out scenes.\n\n";
        out += "## The paper's Table I (their simulator, for reference)\n\n";
        out += &self.paper_table();
        out += "\n## Time per method\n\n| method | training (s, sum over tasks) | evaluation (s, sum) | parameters | inference p50 (ms, per task) |\n|---|---|---|---|---|\n";
        for method in &METHODS {
            let cells: Vec<&Cell> = method.tasks().iter().filter_map(|t| self.cell(method, t)).collect();
            let train: f64 = cells.iter().map(|c| c.train_seconds).sum();
            let eval: f64 = cells.iter().map(|c| c.eval_seconds).sum();
            let params: Vec<String> = cells.iter().map(|c| c.parameters.to_string()).collect();
            let latency: Vec<String> = cells.iter().map(|c| format!("{:.0}", c.latency_ms_p50)).collect();
            out += &format!("| {} | {train:.0} | {eval:.0} | {} | {} |\n", method.label, params.join(", "), latency.join(", "));
        }
        out += &format!(
            "\nTraining time is each run's optimisation wall time (one torch thread); evaluation time includes rendering, prediction, physics and the expert for MED.\n\n## Run\n\n- command: `{}`\n- date: {}\n- machine: {}\n- wall time: {:.0} s, {} jobs, {} at a time{}\n",
            self.command,
            self.date,
            self.machine,
            self.wall_time_s,
            self.total_jobs,
            self.jobs,
            if self.reused > 0 { format!(", {} reused from an earlier run (their time is not in this wall time)", self.reused) } else { String::new() }
        );
        out
    }

    fn csv(&self) -> String {
        let mut out = String::from("method,model_type,task,demos,heldout_episodes,success_rate,med_cm,latency_ms_p50,train_seconds,eval_seconds,parameters\n");
        for c in &self.results {
            out += &format!(
                "{},{},{},{},{},{:.4},{:.4},{:.1},{:.1},{:.1},{}\n",
                c.method, c.model_type, c.task, c.demos, c.episodes, c.success_rate, c.med_cm, c.latency_ms_p50, c.train_seconds, c.eval_seconds, c.parameters
            );
        }
        out
    }
}

pub(super) fn write_reports(out: &Path, report: &Report) -> Result<(), Failure> {
    fs::create_dir_all(out).map_err(|err| Failure::Environment(format!("cannot create {}: {err}", out.display())))?;
    let chart = Bridge::start_default()?.core_table_chart(
        &serde_json::to_string(&report.results).expect("results serialise"),
        &METHODS.iter().map(|m| m.label.to_owned()).collect::<Vec<_>>(),
        &TASKS.iter().map(|t| (*t).to_owned()).collect::<Vec<_>>(),
    )?;
    write_atomically(&out.join("table1.png"), &chart)?;
    write_atomically(&out.join("table1.csv"), report.csv().as_bytes())?;
    write_atomically(&out.join("table1.md"), report.markdown().as_bytes())
}

/// CPU model, cores and memory, from /proc (Linux), for the report.
pub(super) fn machine_description() -> String {
    let cpu = fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| text.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|s| s.trim().to_owned()))
        .unwrap_or_else(|| "unknown CPU".into());
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let memory_gib = fs::read_to_string("/proc/meminfo")
        .ok()
        .and_then(|text| text.lines().next().and_then(|l| l.split_whitespace().nth(1)).and_then(|kb| kb.parse::<f64>().ok()))
        .map_or(String::new(), |kb| format!(", {:.0} GiB", kb / 1024.0 / 1024.0));
    format!("{cpu}, {cores} cores available{memory_gib}, no GPU used")
}

/// Today's date (UTC), YYYY-MM-DD, from `date`.
pub(super) fn today() -> String {
    Command::new("date")
        .args(["-u", "+%F"])
        .output()
        .ok()
        .filter(|out| out.status.success())
        .map_or_else(|| "unknown date".into(), |out| String::from_utf8_lossy(&out.stdout).trim().to_owned())
}

#[cfg(test)]
mod tests {
    use super::versus;

    #[test]
    fn a_comparison_shows_enough_digits_to_tell_the_values_apart() {
        assert_eq!(versus(0.66, 17.52), "0.66 vs 17.52");
        assert_eq!(versus(1.7726, 1.7710), "1.773 vs 1.771");
        assert_eq!(versus(1.77261, 1.77259), "1.7726 vs 1.7726", "stops at four digits");
        assert_eq!(versus(2.5, 2.5), "2.5000 vs 2.5000");
    }
}
