//! End-to-end tests of the real `cnfmp` binary: trajectory commands on files the tests write,
//! and `cnfmp doctor` starting the real embedded interpreter on the project venv.

use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::{Value, json};

mod common;
use common::{arg, cnfmp, stderr};

/// A 2 s, 10 Hz trajectory turning about z, closing the gripper at 1 s.
fn sample_trajectory() -> Value {
    let frames: Vec<Value> = (0..21)
        .map(|k| {
            let t = k as f64 * 0.1;
            let half = 0.25 * t;
            json!({"t": t, "position": [0.1 * t, 0.2 * t.sin(), 0.3], "orientation": [half.cos(), 0.0, 0.0, half.sin()], "gripper": if t < 1.0 { 1.0 } else { 0.0 }})
        })
        .collect();
    json!({"fps": 10.0, "frames": frames, "task": "wall_avoidance"})
}

fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn inspect_prints_the_summary() {
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "traj.json", &sample_trajectory().to_string());
    let output = cnfmp(&["trajectory", "inspect", arg(&file), "--json"]);
    assert!(output.status.success(), "{}", stderr(&output));
    let summary: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(summary["frames"], 21);
    assert!((summary["duration_s"].as_f64().unwrap() - 2.0).abs() < 1e-12);
    assert!((summary["rotation_rad"].as_f64().unwrap() - 1.0).abs() < 1e-9);
    assert_eq!(summary["gripper_closes_at_s"], json!([1.0]));
    let text = cnfmp(&["trajectory", "inspect", arg(&file)]);
    assert!(String::from_utf8_lossy(&text.stdout).contains("path length"));
}

#[test]
fn resample_up_then_down_round_trips() {
    let dir = tempfile::tempdir().unwrap();
    let original = sample_trajectory();
    let file = write(dir.path(), "traj.json", &original.to_string());
    let (up, down) = (dir.path().join("up.json"), dir.path().join("down.json"));
    for (input, fps, out) in [(&file, "30", &up), (&up, "10", &down)] {
        let output = cnfmp(&["trajectory", "resample", arg(input), "--fps", fps, "--out", arg(out)]);
        assert!(output.status.success(), "{}", stderr(&output));
    }
    let up: Value = serde_json::from_str(&std::fs::read_to_string(&up).unwrap()).unwrap();
    assert_eq!(up["frames"].as_array().unwrap().len(), 61);
    let down: Value = serde_json::from_str(&std::fs::read_to_string(&down).unwrap()).unwrap();
    assert_eq!(down["task"], "wall_avoidance", "metadata survives");
    let (a, b) = (original["frames"].as_array().unwrap(), down["frames"].as_array().unwrap());
    assert_eq!(a.len(), b.len());
    for (fa, fb) in a.iter().zip(b) {
        for key in ["position", "orientation"] {
            for (x, y) in fa[key].as_array().unwrap().iter().zip(fb[key].as_array().unwrap()) {
                assert!((x.as_f64().unwrap() - y.as_f64().unwrap()).abs() < 1e-6, "{key}: {fa} vs {fb}");
            }
        }
        assert!((fa["t"].as_f64().unwrap() - fb["t"].as_f64().unwrap()).abs() < 1e-9);
    }
}

#[test]
fn smooth_writes_a_valid_trajectory() {
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "traj.json", &sample_trajectory().to_string());
    let out = dir.path().join("smooth.json");
    let output = cnfmp(&["trajectory", "smooth", arg(&file), "--sigma", "0.1", "--out", arg(&out)]);
    assert!(output.status.success(), "{}", stderr(&output));
    assert!(cnfmp(&["trajectory", "inspect", arg(&out)]).status.success());
}

/// Each bad file: (name, how to break the sample, words the error must contain).
#[test]
fn bad_trajectory_files_are_rejected_with_exit_code_2() {
    let dir = tempfile::tempdir().unwrap();
    let broken = |edit: &dyn Fn(&mut Value)| {
        let mut value = sample_trajectory();
        edit(&mut value);
        value.to_string()
    };
    let cases: Vec<(&str, String, Vec<&str>)> = vec![
        // Python's json.dump writes NaN for float('nan'): not JSON, but common.
        ("nan.json", broken(&|v| v["frames"][3]["position"][1] = json!("NAN_TOKEN")).replace("\"NAN_TOKEN\"", "NaN"), vec!["frames[3].position", "non-finite", "NaN"]),
        ("nonunit.json", broken(&|v| v["frames"][4]["orientation"] = json!([0.9, 0.0, 0.0, 0.1])), vec!["frames[4].orientation", "norm 0.905539", "not 1"]),
        ("backwards.json", broken(&|v| v["frames"][5]["t"] = json!(0.2)), vec!["frames[5].t", "does not increase"]),
        ("missing.json", broken(&|v| { v["frames"][6].as_object_mut().unwrap().remove("gripper"); }), vec!["frames[6]", "missing field `gripper`"]),
        ("notjson.json", "this is { not json".to_owned(), vec!["not valid JSON"]),
        ("gripper.json", broken(&|v| v["frames"][2]["gripper"] = json!(1.5)), vec!["frames[2].gripper", "outside [0, 1]"]),
        ("shape.json", broken(&|v| v["frames"][1]["position"] = json!([0.0, 0.1])), vec!["frames[1].position", "length 3"]),
        ("null.json", broken(&|v| v["frames"][0]["t"] = Value::Null), vec!["frames[0].t", "null"]),
        ("fps.json", broken(&|v| v["fps"] = json!(-5)), vec!["fps", "> 0"]),
    ];
    for (name, text, expected) in cases {
        let file = write(dir.path(), name, &text);
        let out = dir.path().join(format!("out-{name}"));
        for args in [vec!["trajectory", "inspect", arg(&file)], vec!["trajectory", "resample", arg(&file), "--fps", "30", "--out", arg(&out)]] {
            let output = cnfmp(&args);
            let message = stderr(&output);
            assert_eq!(output.status.code(), Some(2), "{name}: {message}");
            for word in &expected {
                assert!(message.contains(word), "{name}: `{word}` missing from: {message}");
            }
            assert!(message.contains(name), "{name}: the error names the file: {message}");
            assert!(!message.contains("panicked"), "{message}");
            assert!(!out.exists(), "{name}: nothing is written on bad input");
        }
    }
}

#[test]
fn missing_input_and_bad_arguments_exit_2() {
    let dir = tempfile::tempdir().unwrap();
    let output = cnfmp(&["trajectory", "inspect", arg(&dir.path().join("nope.json"))]);
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("cannot read"));
    let file = write(dir.path(), "traj.json", &sample_trajectory().to_string());
    let out = dir.path().join("out.json");
    for args in [vec!["--fps", "0"], vec!["--steps", "1"], vec![], vec!["--fps", "3", "--steps", "4"]] {
        let mut full = vec!["trajectory", "resample", arg(&file), "--out", arg(&out)];
        full.extend(args.iter());
        let output = cnfmp(&full);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", stderr(&output));
        assert!(!out.exists());
    }
}

#[test]
fn failed_write_keeps_the_existing_output() {
    let dir = tempfile::tempdir().unwrap();
    let file = write(dir.path(), "traj.json", &sample_trajectory().to_string());
    let out = write(dir.path(), "out.json", "precious");
    let bad = write(dir.path(), "bad.json", "{");
    let output = cnfmp(&["trajectory", "resample", arg(&bad), "--fps", "5", "--out", arg(&out)]);
    assert_eq!(output.status.code(), Some(2));
    assert_eq!(std::fs::read_to_string(&out).unwrap(), "precious");
    let output = cnfmp(&["trajectory", "resample", arg(&file), "--fps", "5", "--out", arg(&out)]);
    assert!(output.status.success());
    assert!(std::fs::read_to_string(&out).unwrap().contains("\"frames\""));
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().filter_map(|e| e.ok()).filter(|e| e.file_name().to_string_lossy().starts_with(".cnfmp-")).collect();
    assert!(leftovers.is_empty(), "no temporary files left behind");
}

#[test]
fn doctor_reports_the_venv_and_pinned_stack() {
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models/wall_avoidance");
    let output = cnfmp(&["doctor", "--json", "--model", model.to_str().unwrap()]);
    assert!(output.status.success(), "doctor failed: {}\n{}", stderr(&output), String::from_utf8_lossy(&output.stdout));
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv").canonicalize().unwrap();
    let prefix = Path::new(report["python"]["prefix"].as_str().unwrap()).canonicalize().unwrap();
    assert_eq!(prefix, venv);
    let check = |name: &str| report["checks"].as_array().unwrap().iter().find(|c| c["name"] == name).cloned().unwrap_or_else(|| panic!("no check {name}"));
    assert!(check("torch")["detail"].as_str().unwrap().starts_with("2.10."));
    assert!(check("mujoco")["detail"].as_str().unwrap().starts_with("4.0.0"));
    assert!(check("lerobot")["detail"].as_str().unwrap().starts_with("0.4.4"));
    assert!(check("torch threads")["detail"].as_str().unwrap().contains("intra-op 1"));
    let render = check("mujoco render");
    assert!(["egl", "osmesa"].contains(&render["backend"].as_str().unwrap()), "{render}");
    assert_eq!(check("bridge zero-copy")["ok"], true);
    // The cold start, stage by stage, ends with the model's warm prediction.
    let stages: Vec<&str> = report["startup"]["stages"].as_array().unwrap().iter().map(|s| s["name"].as_str().unwrap()).collect();
    assert_eq!(stages.first(), Some(&"import numpy and torch"), "{stages:?}");
    assert_eq!(stages.last(), Some(&"warm prediction"), "{stages:?}");
    let total: f64 = report["startup"]["stages"].as_array().unwrap().iter().map(|s| s["ms"].as_f64().unwrap()).sum();
    assert!(total > 0.0 && report["startup"]["process_ms"].as_f64().unwrap() >= total, "{}", report["startup"]);
    let output = cnfmp(&["doctor", "--model", "no-such-model"]);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(stderr(&output).contains("not a model directory"), "{}", stderr(&output));
}

#[test]
fn doctor_without_the_venv_fails_clearly() {
    let dir = tempfile::tempdir().unwrap();
    let output = Command::new(env!("CARGO_BIN_EXE_cnfmp")).arg("doctor").env("CNFMP_VENV", dir.path().join("moved-away")).output().unwrap();
    let message = stderr(&output);
    assert_eq!(output.status.code(), Some(1), "{message}");
    assert!(message.contains("pyvenv.cfg does not exist") && message.contains("make setup"), "{message}");
    assert!(!message.contains("panicked"), "{message}");
}
