//! End-to-end tests of `cnfmp sim` and `cnfmp dataset` through the real binary, embedded
//! interpreter and MuJoCo.

use std::path::Path;

use serde_json::Value;

mod common;
use common::{arg, cnfmp, stderr};


#[test]
fn render_writes_image_masks_and_objects_once() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scene");
    let output = cnfmp(&["sim", "render", "--task", "cube_stacking", "--seed", "1000000", "--out", arg(&out)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let objects: Value = serde_json::from_str(&std::fs::read_to_string(out.join("objects.json")).unwrap()).unwrap();
    assert_eq!(objects["objects"].as_array().unwrap().len(), 3);
    assert!(objects["prompt"].as_str().unwrap().contains("cube"));
    for file in ["image.png", "masks.png"] {
        let bytes = std::fs::read(out.join(file)).unwrap();
        assert_eq!(&bytes[1..4], b"PNG", "{file} is a PNG");
    }
    let again = cnfmp(&["sim", "render", "--task", "cube_stacking", "--seed", "1000000", "--out", arg(&out)]);
    assert_eq!(again.status.code(), Some(2));
    assert!(stderr(&again).contains("already exists"), "{}", stderr(&again));
}

#[test]
fn expert_trajectory_succeeds_and_a_truncated_one_fails() {
    let dir = tempfile::tempdir().unwrap();
    let expert = dir.path().join("expert.json");
    let output = cnfmp(&["sim", "expert", "--task", "cube_stacking", "--seed", "1000001", "--out", arg(&expert)]);
    assert!(output.status.success(), "{}", stderr(&output));
    let run = |file: &Path| {
        let output = cnfmp(&["sim", "execute", "--task", "cube_stacking", "--seed", "1000001", "--trajectory", arg(file)]);
        assert!(output.status.success(), "execute exits 0 either way: {}", stderr(&output));
        serde_json::from_slice::<Value>(&output.stdout).unwrap()
    };
    let verdict = run(&expert);
    assert_eq!(verdict["success"], true, "{verdict}");
    // Keep only the first 2 s: nothing gets stacked.
    let mut trajectory: Value = serde_json::from_str(&std::fs::read_to_string(&expert).unwrap()).unwrap();
    trajectory["frames"].as_array_mut().unwrap().truncate(100);
    let truncated = dir.path().join("truncated.json");
    std::fs::write(&truncated, trajectory.to_string()).unwrap();
    let verdict = run(&truncated);
    assert_eq!(verdict["success"], false);
    assert!(verdict["reasons"].as_array().unwrap().iter().any(|r| r.as_str().unwrap().contains("not stacked")), "{verdict}");
}

#[test]
fn bad_sim_input_exits_2() {
    let dir = tempfile::tempdir().unwrap();
    let expert = dir.path().join("expert.json");
    assert!(cnfmp(&["sim", "expert", "--task", "cube_stacking", "--seed", "3", "--out", arg(&expert)]).status.success());
    let mut trajectory: Value = serde_json::from_str(&std::fs::read_to_string(&expert).unwrap()).unwrap();
    trajectory["frames"][40]["position"][2] = Value::from(3.0);
    let outside = dir.path().join("outside.json");
    std::fs::write(&outside, trajectory.to_string()).unwrap();
    let garbage = dir.path().join("garbage.json");
    std::fs::write(&garbage, r#"{"fps": 10, "frames": ["#).unwrap();
    let (never_written, no_dataset) = (dir.path().join("x.json"), dir.path().join("d"));
    let cases: [(Vec<&str>, &str); 4] = [
        (vec!["sim", "execute", "--task", "cube_stacking", "--seed", "3", "--trajectory", arg(&outside)], "leaves the workspace"),
        (vec!["sim", "execute", "--task", "cube_stacking", "--seed", "3", "--trajectory", arg(&garbage)], "not valid JSON"),
        (vec!["sim", "expert", "--task", "juggling", "--seed", "3", "--out", arg(&never_written)], "unknown task 'juggling'"),
        (vec!["dataset", "generate", "--task", "cube_stacking", "--episodes", "0", "--out", arg(&no_dataset)], "episodes"),
    ];
    for (args, expected) in cases {
        let output = cnfmp(&args);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", stderr(&output));
        assert!(stderr(&output).contains(expected), "{args:?}: {}", stderr(&output));
        assert!(!stderr(&output).contains("Traceback") && !stderr(&output).contains("panicked"));
    }
    assert!(!never_written.exists() && !no_dataset.exists());
}

#[test]
fn dataset_generate_writes_a_dataset_and_refuses_to_overwrite_it() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("demos");
    let args = ["dataset", "generate", "--task", "cube_stacking", "--episodes", "1", "--seed", "7", "--workers", "1", "--out", arg(&out)];
    let output = cnfmp(&args);
    assert!(output.status.success(), "{}", stderr(&output));
    let report: Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["episodes"], 1);
    assert_eq!(report["seeds"], serde_json::json!([7]));
    let info: Value = serde_json::from_str(&std::fs::read_to_string(out.join("meta/info.json")).unwrap()).unwrap();
    assert_eq!(info["codebase_version"], "v3.0");
    assert_eq!(info["total_episodes"], 1);
    let again = cnfmp(&args);
    assert_eq!(again.status.code(), Some(2));
    assert!(stderr(&again).contains("already exists"));
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().filter_map(|e| e.ok()).map(|e| e.file_name()).collect();
    assert_eq!(leftovers.len(), 1, "only the dataset, no staging directory: {leftovers:?}");
}
