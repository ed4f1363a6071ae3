//! `cnfmp benchmark table1 --quick` end to end: real datasets, real trainings of every method,
//! real evaluations by physics, and the report; then a rerun that reuses every finished job,
//! and bad arguments; `cnfmp benchmark data-efficiency` at tiny sizes the same way. The
//! numbers of --quick mean nothing; the machinery is what is tested.

mod common;

use common::{arg, cnfmp, stderr};

const METHODS: [&str; 5] = ["CNN-CNMP (low)", "CNN-CNMP (high)", "NFMP (grid)", "ours without gating (low)", "ours (low)"];
const TASKS: [&str; 4] = ["wall_avoidance", "incline_pick_place", "cup_stacking", "cube_stacking"];

#[test]
fn quick_table1_trains_and_evaluates_every_method_and_a_rerun_reuses_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("reports");
    let shipped_configs = common::repo().join("configs/core");
    let quick_configs = common::repo().join("configs/quick");
    let table1 = |configs: &std::path::Path| {
        cnfmp(&["benchmark", "table1", "--quick", "--out", arg(&out), "--episodes", "2", "--configs", arg(configs), "--quick-configs", arg(&quick_configs)])
    };
    let run = table1(&shipped_configs);
    assert!(run.status.success(), "{}", stderr(&run));

    // The CSV: one row per method and task it is evaluated on (NFMP: wall only), numbers in range.
    let csv = std::fs::read_to_string(out.join("table1.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4 * 4 + 1, "{csv}");
    for method in METHODS {
        let count = rows.iter().filter(|r| r[0] == method).count();
        assert_eq!(count, if method == "NFMP (grid)" { 1 } else { 4 }, "{method}: {csv}");
    }
    for row in &rows {
        let (success, med): (f64, f64) = (row[5].parse().unwrap(), row[6].parse().unwrap());
        assert!((0.0..=1.0).contains(&success) && med.is_finite() && med > 0.0, "{row:?}");
        assert_eq!(row[4], "2", "held-out episodes: {row:?}");
        let demos: u64 = row[3].parse().unwrap();
        assert_eq!(demos, if row[0] == "NFMP (grid)" { 27 } else if row[0] == "CNN-CNMP (high)" { 5 } else { 3 }, "{row:?}");
    }

    // The Markdown report: the paper's layout, the paper's numbers, the claims, the command.
    let md = std::fs::read_to_string(out.join("table1.md")).unwrap();
    for method in METHODS {
        assert!(md.contains(&format!("| {method} |")), "{method} missing:\n{md}");
    }
    assert!(md.contains("| wall avoidance | incline pick-place | cup stacking | cube stacking |"), "{md}");
    assert!(md.contains("0.48 / 1.00"), "the paper's numbers are missing:\n{md}");
    assert!(md.contains("cnfmp benchmark table1 --quick"), "{md}");
    assert!(md.contains("## The claims, checked"), "{md}");
    for task in TASKS {
        assert!(md.contains(&format!("{task}: ours (low) beats CNN-CNMP (low)")), "{task}:\n{md}");
    }
    let png = std::fs::read(out.join("table1.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 5_000, "{} bytes", png.len());
    let work = out.join("table1-quick-work");
    assert!(work.join("models/cnfmp-low/cube_stacking/model.safetensors").is_file());
    assert!(work.join("datasets/wall_avoidance-27-from-900000").is_dir());

    // A rerun reuses every job (it says so, and trains nothing) and writes the same table.
    let rerun = table1(&shipped_configs);
    assert!(rerun.status.success(), "{}", stderr(&rerun));
    assert!(stderr(&rerun).contains("reusing 43 finished job(s)"), "{}", stderr(&rerun));
    assert_eq!(std::fs::read_to_string(out.join("table1.csv")).unwrap(), csv);

    // A changed training config retrains the models it concerns (and evaluates them again);
    // every other job is still reused.
    let configs = dir.path().join("configs");
    std::fs::create_dir(&configs).unwrap();
    for entry in std::fs::read_dir(&shipped_configs).unwrap() {
        let file = entry.unwrap().path();
        std::fs::copy(&file, configs.join(file.file_name().unwrap())).unwrap();
    }
    std::fs::write(configs.join("wall_avoidance.json"), r#"{"num_endpoints": 3}"#).unwrap();
    let changed = table1(&configs);
    assert!(changed.status.success(), "{}", stderr(&changed));
    for key in ["cnfmp-low", "cnfmp-nogate-low"] {
        assert!(stderr(&changed).contains(&format!("{key}/wall_avoidance: its training config changed")), "{}", stderr(&changed));
    }
    assert!(stderr(&changed).contains("reusing 39 finished job(s)"), "{}", stderr(&changed));
    let used = std::fs::read_to_string(work.join("configs/cnfmp-low-wall_avoidance.txt")).unwrap();
    assert!(used.contains("\"num_endpoints\": 3"), "{used}");
}

#[test]
fn bad_arguments_are_refused_before_any_work() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("reports");
    let zero = cnfmp(&["benchmark", "table1", "--quick", "--out", arg(&out), "--episodes", "0"]);
    assert_eq!(zero.status.code(), Some(2), "{}", stderr(&zero));
    let not_a_dir = dir.path().join("file.json");
    std::fs::write(&not_a_dir, "{}").unwrap();
    let configs = cnfmp(&["benchmark", "table1", "--quick", "--out", arg(&out), "--configs", arg(&not_a_dir)]);
    assert_eq!(configs.status.code(), Some(2), "{}", stderr(&configs));
    assert!(stderr(&configs).contains("is not a directory"), "{}", stderr(&configs));
    let broken = dir.path().join("configs");
    std::fs::create_dir(&broken).unwrap();
    std::fs::write(broken.join("wall_avoidance.json"), "[1, 2]").unwrap();
    let quick_configs = common::repo().join("configs/quick");
    let run = cnfmp(&["benchmark", "table1", "--quick", "--out", arg(&out), "--configs", arg(&broken), "--quick-configs", arg(&quick_configs)]);
    assert_eq!(run.status.code(), Some(2), "{}", stderr(&run));
    assert!(stderr(&run).contains("is not a JSON object of config fields"), "{}", stderr(&run));
    assert!(!out.join("table1.md").exists());
}

#[test]
fn data_efficiency_trains_one_model_per_size_and_a_rerun_reuses_them() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("reports");
    let run = || {
        cnfmp(&["benchmark", "data-efficiency", "--tasks", "wall_avoidance", "--sizes", "3,2", "--steps", "30", "--episodes", "2", "--out", arg(&out)])
    };
    let first = run();
    assert!(first.status.success(), "{}", stderr(&first));
    let csv = std::fs::read_to_string(out.join("data_efficiency.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.iter().map(|r| (r[0], r[1])).collect::<Vec<_>>(), [("wall_avoidance", "2"), ("wall_avoidance", "3")], "{csv}");
    for row in &rows {
        let (success, med): (f64, f64) = (row[3].parse().unwrap(), row[4].parse().unwrap());
        assert!((0.0..=1.0).contains(&success) && med.is_finite() && med > 0.0, "{row:?}");
        assert_eq!(row[2], "2", "held-out episodes: {row:?}");
    }
    let md = std::fs::read_to_string(out.join("data_efficiency.md")).unwrap();
    assert!(md.contains("| task | 2 demos | 3 demos |") && md.contains("| wall_avoidance | "), "{md}");
    assert!(md.contains("30 steps: a smoke run") && md.contains("cnfmp benchmark data-efficiency"), "{md}");
    let png = std::fs::read(out.join("data_efficiency.png")).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 5_000, "{} bytes", png.len());
    // The 2-demonstration set is the first two seeds of the 3-demonstration one.
    let work = out.join("data-efficiency-work");
    assert!(work.join("models/wall_avoidance-2-seed0-steps30/model.safetensors").is_file());
    let rerun = run();
    assert!(rerun.status.success(), "{}", stderr(&rerun));
    assert!(stderr(&rerun).contains("reusing 6 finished job(s)"), "{}", stderr(&rerun));
    assert_eq!(std::fs::read_to_string(out.join("data_efficiency.csv")).unwrap(), csv);

    let bad = cnfmp(&["benchmark", "data-efficiency", "--sizes", "0,5", "--out", arg(&out)]);
    assert_eq!(bad.status.code(), Some(2), "{}", stderr(&bad));
    assert!(stderr(&bad).contains("--sizes must be numbers of demonstrations >= 1"), "{}", stderr(&bad));
}
