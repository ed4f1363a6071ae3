//! End-to-end tests of `cnfmp dataset convert` and `cnfmp dataset validate` on the real
//! binary: lerobot writes and reads the datasets, h5py writes the HDF5 input.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use cnfmp::commands::demo::{ServerProcess, http_client};
use cnfmp::images;
use cnfmp::trajectory::Trajectory;
use cnfmp::trajectory::resample::{ResampleTarget, resample};
use serde_json::Value;

use common::{TINY_CONFIG, arg, cnfmp, copy_tree, repo, stderr};

fn example() -> PathBuf {
    repo().join("datasets/examples/raw")
}

fn ok(output: &Output, what: &str) -> Value {
    assert!(output.status.success(), "{what} failed: {}", stderr(output));
    serde_json::from_slice(&output.stdout).unwrap_or(Value::Null)
}

fn convert(from: &str, out: &Path, extra: &[&str]) -> Output {
    let mut args = vec!["dataset", "convert", "--from", from, "--out", arg(out)];
    args.extend_from_slice(extra);
    cnfmp(&args)
}

fn close(a: &Trajectory, b: &Trajectory, tolerance: f64) {
    assert_eq!(a.frames.len(), b.frames.len());
    for (x, y) in a.frames.iter().zip(&b.frames) {
        assert!((x.t - a.start() - (y.t - b.start())).abs() < tolerance, "t {} vs {}", x.t, y.t);
        assert!((x.pose.position - y.pose.position).norm() < tolerance, "{:?} vs {:?}", x.pose.position, y.pose.position);
        assert!(x.pose.orientation.angle_to(&y.pose.orientation) < tolerance.sqrt() * 1e-2);
        assert!((x.gripper - y.gripper).abs() < tolerance);
    }
}

#[test]
fn raw_to_lerobot_to_raw_round_trips_validates_and_trains() {
    let dir = tempfile::tempdir().unwrap();
    let dataset = dir.path().join("lerobot");
    let report = ok(&convert(&format!("raw:{}", example().display()), &dataset, &[]), "convert");
    assert_eq!(report["converted"], 3);
    assert_eq!(report["fps"], 10.0);
    assert!(dataset.join(cnfmp::convert::REPORT_FILE).is_file());
    assert!(!dir.path().join(".lerobot.convert").exists(), "the staging area is removed");

    let validation = ok(&cnfmp(&["dataset", "validate", arg(&dataset), "--json"]), "validate");
    assert_eq!(validation["passed"], true, "{validation}");
    let names: Vec<&str> = validation["checks"].as_array().unwrap().iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert!(names.contains(&"lerobot read-back") && names.iter().any(|n| n.starts_with("lerobot-doctor")), "{names:?}");

    let back = dir.path().join("raw");
    let exported = ok(&convert(&format!("lerobot:{}", dataset.display()), &back, &["--to", "raw"]), "export");
    assert_eq!(exported["converted"], 3);
    for name in ["episode_000", "episode_001", "episode_002"] {
        let (source, copy) = (example().join(name), back.join(name));
        let rgb = |path: &Path| images::read_rgb(path).unwrap();
        assert_eq!(rgb(&source.join("image.png")), rgb(&copy.join("image.png")), "{name}: image");
        assert!(!copy.join("frames").exists(), "a static camera exports one image");
        let original = match Trajectory::load(&source.join("trajectory.json")) {
            Ok(trajectory) => trajectory,
            Err(_) => {
                let text = std::fs::read_to_string(source.join("trajectory.csv")).unwrap();
                cnfmp::trajectory::csv::from_csv_str(&text, 10.0).unwrap()
            }
        };
        // Episode 2 was recorded at 25 Hz: the dataset holds it resampled to 10 Hz.
        let expected = resample(&original, ResampleTarget::Fps(10.0)).unwrap();
        close(&expected, &Trajectory::load(&copy.join("trajectory.json")).unwrap(), 1e-6);
        let meta: Value = serde_json::from_str(&std::fs::read_to_string(copy.join("meta.json")).unwrap()).unwrap();
        let source_meta: Value = serde_json::from_str(&std::fs::read_to_string(source.join("meta.json")).unwrap()).unwrap();
        assert_eq!(meta["prompt"], source_meta["prompt"]);
        assert_eq!(meta["seed"], source_meta["seed"]);
    }
    // Per-object masks came in as masks/<object>.png; they come back as one label map.
    let labels = images::read_label_map(&back.join("episode_001/masks.png")).unwrap();
    let wall = images::read_label_map(&example().join("episode_001/masks/wall.png")).unwrap();
    for (label, mask) in labels.pixels.iter().zip(&wall.pixels) {
        assert_eq!(*label == 1, *mask != 0);
    }

    // raw -> lerobot once more: the round trip is a fixed point.
    let again = dir.path().join("again");
    ok(&convert(&format!("raw:{}", back.display()), &again, &[]), "reconvert");
    let twice = dir.path().join("raw2");
    ok(&convert(&format!("lerobot:{}", again.display()), &twice, &["--to", "raw"]), "re-export");
    for name in ["episode_000", "episode_001", "episode_002"] {
        for file in ["image.png", "masks.png", "trajectory.json", "objects.json"] {
            let same = std::fs::read(back.join(name).join(file)).unwrap() == std::fs::read(twice.join(name).join(file)).unwrap();
            assert!(same, "{name}/{file} changed on the second round trip");
        }
    }

    // The converted dataset trains.
    let config = dir.path().join("tiny.json");
    std::fs::write(&config, TINY_CONFIG).unwrap();
    let model = dir.path().join("model");
    let trained = cnfmp(&["train", "--dataset", arg(&dataset), "--out", arg(&model), "--config", arg(&config), "--steps", "10"]);
    let trained = ok(&trained, "train");
    assert_eq!(trained["demos"], 3);
    assert!(model.join("model.safetensors").is_file());
}

/// Writes a broken copy of example episode 0 under `root/name` and lets `spoil` damage it.
fn broken_episode(root: &Path, name: &str, spoil: impl FnOnce(&Path)) {
    let episode = root.join(name);
    copy_tree(&example().join("episode_000"), &episode);
    spoil(&episode);
}

fn edit_trajectory(episode: &Path, edit: impl FnOnce(&mut Value)) {
    let path = episode.join("trajectory.json");
    let mut value: Value = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    edit(&mut value);
    std::fs::write(&path, serde_json::to_string(&value).unwrap().replace("\"NAN\"", "NaN")).unwrap();
}

#[test]
fn bad_episodes_are_reported_with_file_and_reason_and_strict_stops() {
    let dir = tempfile::tempdir().unwrap();
    let source = dir.path().join("source");
    copy_tree(&example(), &source);
    broken_episode(&source, "bad_image", |e| {
        let bytes = std::fs::read(e.join("image.png")).unwrap();
        std::fs::write(e.join("image.png"), &bytes[..bytes.len() / 2]).unwrap();
    });
    broken_episode(&source, "bad_masks_size", |e| {
        let small = images::Image { width: 8, height: 8, channels: 1, pixels: vec![0; 64] };
        images::write_png(&e.join("masks.png"), &small).unwrap();
    });
    broken_episode(&source, "bad_nan", |e| edit_trajectory(e, |t| t["frames"][3]["position"][1] = "NAN".into()));
    broken_episode(&source, "bad_time", |e| edit_trajectory(e, |t| t["frames"][5]["t"] = 0.0.into()));
    broken_episode(&source, "bad_objects", |e| std::fs::write(e.join("objects.json"), r#"["wall"]"#).unwrap());
    broken_episode(&source, "bad_missing_image", |e| std::fs::remove_file(e.join("image.png")).unwrap());

    let out = dir.path().join("out");
    let report = ok(&convert(&format!("raw:{}", source.display()), &out, &["--workers", "3"]), "convert");
    assert_eq!(report["episodes"], 9);
    assert_eq!(report["converted"], 3);
    let skipped = report["skipped"].as_array().unwrap();
    let reason = |episode: &str| -> (String, String) {
        let entry = skipped.iter().find(|s| s["episode"] == episode).unwrap_or_else(|| panic!("{episode} not reported: {skipped:?}"));
        (entry["file"].as_str().unwrap().to_owned(), entry["reason"].as_str().unwrap().to_owned())
    };
    let (file, why) = reason("bad_image");
    assert!(file.ends_with("bad_image/image.png") && why.contains("not a readable PNG"), "{file}: {why}");
    let (file, why) = reason("bad_masks_size");
    assert!(file.ends_with("masks.png") && why.contains("8x8") && why.contains("same size"), "{file}: {why}");
    let (file, why) = reason("bad_nan");
    assert!(file.ends_with("trajectory.json") && why.contains("frames[3].position") && why.contains("NaN"), "{file}: {why}");
    let (_, why) = reason("bad_time");
    assert!(why.contains("frames[5].t") && why.contains("does not increase"), "{why}");
    let (_, why) = reason("bad_objects");
    assert!(why.contains("unknown object") && why.contains("label 2"), "{why}");
    let (file, why) = reason("bad_missing_image");
    assert!(file.ends_with("image.png") && why.contains("cannot open"), "{file}: {why}");
    let stored: Value = serde_json::from_str(&std::fs::read_to_string(out.join(cnfmp::convert::REPORT_FILE)).unwrap()).unwrap();
    assert_eq!(stored["skipped"].as_array().unwrap().len(), 6);

    let strict = dir.path().join("strict");
    let output = convert(&format!("raw:{}", source.display()), &strict, &["--strict", "--workers", "1"]);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(stderr(&output).contains("episode bad_image is bad (--strict)"), "{}", stderr(&output));
    assert!(!strict.exists(), "a failed conversion leaves no dataset");

    // validate: a damaged dataset fails with the check named; a non-dataset is bad input.
    let damaged = dir.path().join("damaged");
    copy_tree(&out, &damaged);
    let parquet = damaged.join("data/chunk-000/file-000.parquet");
    let bytes = std::fs::read(&parquet).unwrap();
    std::fs::write(&parquet, &bytes[..bytes.len() / 3]).unwrap();
    let output = cnfmp(&["dataset", "validate", arg(&damaged)]);
    assert_eq!(output.status.code(), Some(2), "{}", stderr(&output));
    assert!(String::from_utf8_lossy(&output.stdout).contains("FAIL lerobot read-back"), "{}", String::from_utf8_lossy(&output.stdout));
    let output = cnfmp(&["dataset", "validate", arg(&source)]);
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("not a LeRobot dataset"), "{}", stderr(&output));

    // The output exists now: a second conversion into it is refused, and nothing is touched.
    let output = convert(&format!("raw:{}", source.display()), &out, &[]);
    assert_eq!(output.status.code(), Some(2));
    assert!(stderr(&output).contains("already exists"), "{}", stderr(&output));
    for (args, message) in [
        (vec!["--from", "zarr:x"], "unknown format"),
        (vec!["--from", "raw:/no/such/dir"], "no such file"),
    ] {
        let mut all = vec!["dataset", "convert", "--out", arg(&strict)];
        all.extend(args);
        let output = cnfmp(&all);
        assert_eq!(output.status.code(), Some(2), "{message}");
        assert!(stderr(&output).contains(message), "{}", stderr(&output));
    }
}

fn python() -> PathBuf {
    repo().join(".venv/bin/python")
}

#[test]
fn robomimic_hdf5_converts() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("demos.hdf5");
    // Three demos at 20 Hz (recorded in env_args); demo_2 has a NaN position.
    let script = r#"
import json, sys
import h5py, numpy as np
rng = np.random.default_rng(0)
with h5py.File(sys.argv[1], "w") as f:
    data = f.create_group("data")
    data.attrs["env_args"] = json.dumps({"env_name": "Lift", "env_kwargs": {"control_freq": 20}})
    for k in range(3):
        g = data.create_group(f"demo_{k}")
        g.attrs["lang"] = f"lift the cube {k}"
        g.attrs["objects"] = json.dumps(["cube"])
        T = 12
        image = rng.integers(0, 255, (T, 16, 24, 3), dtype=np.uint8)
        masks = np.zeros((T, 16, 24), np.uint8); masks[:, 4:9, 5:12] = 1
        pos = np.stack([np.linspace(0, 0.1, T), np.full(T, 0.2), np.linspace(0.3, 0.1, T)], 1)
        if k == 2: pos[4, 0] = np.nan
        angle = np.linspace(0, 0.5, T)
        quat_xyzw = np.stack([np.zeros(T), np.zeros(T), np.sin(angle / 2), np.cos(angle / 2)], 1)
        qpos = np.stack([np.linspace(0.04, 0.01, T), -np.linspace(0.04, 0.01, T)], 1)
        g.create_dataset("obs/agentview_image", data=image)
        g.create_dataset("obs/agentview_masks", data=masks)
        g.create_dataset("obs/robot0_eye_in_hand_image", data=image)
        g.create_dataset("obs/robot0_eef_pos", data=pos)
        g.create_dataset("obs/robot0_eef_quat", data=quat_xyzw)
        g.create_dataset("obs/robot0_gripper_qpos", data=qpos)
        g.create_dataset("actions", data=np.zeros((T, 7)))
"#;
    let status = Command::new(python()).args(["-c", script, arg(&file)]).status().unwrap();
    assert!(status.success());

    let dataset = dir.path().join("lerobot");
    let report = ok(&convert(&format!("hdf5:{}", file.display()), &dataset, &[]), "convert hdf5");
    assert_eq!(report["fps"], 20.0);
    assert_eq!(report["converted"], 2);
    let skipped = report["skipped"].as_array().unwrap();
    assert_eq!(skipped.len(), 1);
    assert!(skipped[0]["file"].as_str().unwrap().ends_with("data/demo_2"));
    assert!(skipped[0]["reason"].as_str().unwrap().contains("not a finite number"), "{skipped:?}");
    ok(&cnfmp(&["dataset", "validate", arg(&dataset)]), "validate");

    let back = dir.path().join("raw");
    ok(&convert(&format!("lerobot:{}", dataset.display()), &back, &["--to", "raw"]), "export");
    let trajectory = Trajectory::load(&back.join("demo_1/trajectory.json")).unwrap();
    assert_eq!(trajectory.frames.len(), 12);
    let last = trajectory.frames[11];
    assert!((last.t - 11.0 / 20.0).abs() < 1e-6);
    assert!((last.pose.position - nalgebra::Vector3::new(0.1, 0.2, 0.1)).norm() < 1e-6);
    // [x, y, z, w] in the file became [w, x, y, z]: a 0.5 rad turn about z.
    assert!((last.pose.orientation.angle() - 0.5).abs() < 1e-5);
    assert!((last.pose.orientation.axis().unwrap().z - 1.0).abs() < 1e-6);
    // Fingers at +-0.01 m: 0.02 m of the Panda's 0.08 m.
    assert!((last.gripper - 0.25).abs() < 1e-6, "{}", last.gripper);
    assert!(back.join("demo_1/frames").is_dir(), "a moving camera keeps its frames");
    let meta: Value = serde_json::from_str(&std::fs::read_to_string(back.join("demo_1/meta.json")).unwrap()).unwrap();
    assert_eq!(meta["prompt"], "lift the cube 1");
    let labels = images::read_label_map(&back.join("demo_1/masks.png")).unwrap();
    assert_eq!((labels.width, labels.height, labels.max_label()), (24, 16, 1));
}

/// Every file under `dir` (relative path -> bytes), except the conversion report.
fn tree(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(current) = stack.pop() {
        for entry in std::fs::read_dir(&current).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else if !path.ends_with(cnfmp::convert::REPORT_FILE) {
                files.push((path.strip_prefix(dir).unwrap().display().to_string(), std::fs::read(&path).unwrap()));
            }
        }
    }
    files.sort();
    files
}

#[test]
fn a_conversion_killed_midway_resumes_to_the_same_dataset() {
    let dir = tempfile::tempdir().unwrap();
    let source = dir.path().join("source");
    // 24 episodes: example episodes under new names.
    for k in 0..24 {
        copy_tree(&example().join(format!("episode_00{}", k % 3)), &source.join(format!("ep_{k:03}")));
    }
    let from = format!("raw:{}", source.display());

    let reference = dir.path().join("reference");
    ok(&convert(&from, &reference, &[]), "uninterrupted conversion");

    let out = dir.path().join("out");
    let staging = dir.path().join(".out.convert");
    let mut child = Command::new(env!("CARGO_BIN_EXE_cnfmp"))
        .args(["dataset", "convert", "--from", &from, "--out", arg(&out), "--workers", "1"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Kill it once lerobot has started writing the dataset (staging is done by then).
    let deadline = Instant::now() + Duration::from_secs(120);
    while !staging.join("output/data").exists() {
        assert!(Instant::now() < deadline, "the conversion never started writing");
        assert!(child.try_wait().unwrap().is_none(), "the conversion finished before it could be killed");
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill().unwrap(); // SIGKILL
    child.wait().unwrap();
    assert!(!out.exists(), "an interrupted conversion leaves no dataset at --out");

    let report = ok(&convert(&from, &out, &[]), "resumed conversion");
    assert_eq!(report["resumed"], 24, "the staged episodes are reused");
    assert_eq!(report["converted"], 24);
    assert!(!staging.exists());
    ok(&cnfmp(&["dataset", "validate", arg(&out)]), "validate");

    // Equal to the uninterrupted run: both exported back to raw, file by file.
    let (a, b) = (dir.path().join("a"), dir.path().join("b"));
    ok(&convert(&format!("lerobot:{}", reference.display()), &a, &["--to", "raw"]), "export reference");
    ok(&convert(&format!("lerobot:{}", out.display()), &b, &["--to", "raw"]), "export resumed");
    let (ta, tb) = (tree(&a), tree(&b));
    assert_eq!(ta.len(), tb.len());
    assert!(ta.len() >= 24 * 5);
    for ((name_a, bytes_a), (name_b, bytes_b)) in ta.iter().zip(&tb) {
        assert_eq!(name_a, name_b);
        assert!(bytes_a == bytes_b, "{name_a} differs");
    }
}

/// A recording as `lerobot-record` writes one: two video cameras at 320x240, 15 fps, a
/// rotation-vector end-effector pose with the gripper in millimetres, task prompts, no masks
/// (simulated pick-and-place scenes drawn onto the frames). Also writes `scene.png`,
/// `masks.png` and `objects.json` of its first episode's scene for `predict`.
fn lerobot_recording(root: &Path) {
    let script = r#"
import json, os, sys
import cv2, numpy as np
from PIL import Image
from cnfmp import geometry
from cnfmp.data import generate
from lerobot.datasets.lerobot_dataset import LeRobotDataset
root, scene_dir = sys.argv[1], sys.argv[2]
names = ["ee.x", "ee.y", "ee.z", "ee.rx", "ee.ry", "ee.rz", "gripper.pos"]
video = {"dtype": "video", "shape": (240, 320, 3), "names": ["height", "width", "channels"]}
dataset = LeRobotDataset.create(repo_id="lab/pick", fps=15, root=root, use_videos=True, features={
    "observation.images.front": video, "observation.images.wrist": video,
    "action": {"dtype": "float32", "shape": (7,), "names": names}})
def frame(image, nearest=False):
    out = np.full((240, 320) + image.shape[2:], 128 if image.ndim == 3 else 0, np.uint8)
    out[:, 40:280] = cv2.resize(image, (240, 240), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR)
    return out
for k, speed in enumerate([1.0, 1.4, 0.8]):
    ep = generate.simulate_episode("language_pick_place", 400 + k)
    a = ep["action"]
    motion = np.concatenate([a[:, :3], geometry.to_rotation(a[:, 3:7]).as_rotvec(), a[:, 7:] * 85], axis=1)
    steps = np.linspace(0, len(motion) - 1, int(len(motion) * 1.5 * speed))
    motion = np.stack([np.interp(steps, np.arange(len(motion)), c) for c in motion.T], axis=1)
    front = frame(ep["images"][0])
    for row in motion:
        dataset.add_frame({"observation.images.front": front, "observation.images.wrist": front[::-1].copy(),
                           "action": row.astype(np.float32), "task": ep["prompt"]})
    dataset.save_episode()
    if k == 0:
        os.makedirs(scene_dir)
        Image.fromarray(front).save(os.path.join(scene_dir, "image.png"))
        # The prompt names the first two objects (target, destination); the rest are distractors.
        masks = np.where(ep["masks"][0] > 2, 0, ep["masks"][0]).astype(np.uint8)
        Image.fromarray(frame(masks, nearest=True)).save(os.path.join(scene_dir, "masks.png"))
        json.dump(ep["objects"][:2], open(os.path.join(scene_dir, "objects.json"), "w"))
        open(os.path.join(scene_dir, "prompt.txt"), "w").write(ep["prompt"])
dataset.finalize()
"#;
    let status = Command::new(python())
        .args(["-c", script, arg(&root.join("recording")), arg(&root.join("scene"))])
        .env("PYTHONPATH", repo().join("python"))
        .status()
        .unwrap();
    assert!(status.success());
}

#[test]
fn a_lerobot_recording_is_annotated_trained_and_predicted() {
    let dir = tempfile::tempdir().unwrap();
    lerobot_recording(dir.path());
    let recording = dir.path().join("recording");
    let annotated = dir.path().join("annotated");
    let model = dir.path().join("model");
    let config = dir.path().join("tiny.json");
    std::fs::write(&config, TINY_CONFIG).unwrap();
    let bad = |output: &Output, message: &str| {
        assert_eq!(output.status.code(), Some(2), "{}", stderr(output));
        assert!(stderr(output).contains(message), "{}", stderr(output));
    };

    bad(&cnfmp(&["dataset", "annotate", "--dataset", arg(&recording), "--out", arg(&annotated)]), "choose one with --camera");
    bad(&cnfmp(&["train", "--dataset", arg(&recording), "--out", arg(&model)]), "cnfmp dataset annotate");
    assert!(!annotated.exists() && !model.exists());

    let front = "observation.images.front";
    let report = ok(&cnfmp(&["dataset", "annotate", "--dataset", arg(&recording), "--out", arg(&annotated), "--camera", front]), "annotate");
    assert_eq!((report["annotated"].as_u64(), report["episodes"].as_u64()), (Some(3), Some(3)), "{report}");
    assert!(Path::new(report["contact_sheet"].as_str().unwrap()).is_file());
    let checks = cnfmp(&["dataset", "validate", arg(&annotated)]);
    assert!(checks.status.success(), "{}", String::from_utf8_lossy(&checks.stdout));
    assert!(String::from_utf8_lossy(&checks.stdout).contains("PASS motion layout: action: ee.x ee.y ee.z ee.rx ee.ry ee.rz gripper.pos (rotvec)"));

    let train = |extra: &[&str]| {
        let mut args = vec!["train", "--dataset", arg(&annotated), "--out", arg(&model), "--config", arg(&config), "--steps", "20"];
        args.extend_from_slice(extra);
        cnfmp(&args)
    };
    bad(&train(&["--camera", "observation.images.wrist"]), "masks were made on camera");
    bad(&train(&["--motion-from", "observation.state"]), "lacks feature(s) observation.state");
    bad(&train(&["--motion-names", "x,y,c,d,e,f,gripper"]), "neither an end-effector pose nor joint space");
    ok(&train(&[]), "train");
    let card = std::fs::read_to_string(model.join("README.md")).unwrap();
    assert!(card.contains("3 demonstrations with 2 gripper event(s)") && card.contains("(rotvec); gripper 0..") && card.contains(" read as 0..1"), "{card}");

    let scene = dir.path().join("scene");
    let trajectory = dir.path().join("trajectory.json");
    ok(&cnfmp(&["predict", "--model", arg(&model), "--image", arg(&scene.join("image.png")), "--masks", arg(&scene.join("masks.png")),
                "--objects", arg(&scene.join("objects.json")), "--out", arg(&trajectory)]), "predict");
    let predicted = Trajectory::load(&trajectory).unwrap();
    assert!(predicted.frames.len() > 20);
    // The same frames in the recording's own form: its names, a rotation vector, millimetres.
    let recorded = &predicted.metadata["recorded"];
    assert_eq!(recorded["names"], serde_json::json!(["ee.x", "ee.y", "ee.z", "ee.rx", "ee.ry", "ee.rz", "gripper.pos"]));
    assert_eq!(recorded["values"].as_array().unwrap().len(), predicted.frames.len());
    // The annotation recorded each slot's prompt role, so a prompt drives the model too.
    let prompt = std::fs::read_to_string(scene.join("prompt.txt")).unwrap();
    let from_prompt = dir.path().join("from_prompt.json");
    ok(&cnfmp(&["predict", "--model", arg(&model), "--image", arg(&scene.join("image.png")), "--prompt", &prompt, "--out", arg(&from_prompt)]), "predict --prompt");
    assert_eq!(Trajectory::load(&from_prompt).unwrap().frames.len(), predicted.frames.len());

    // Served over HTTP (the only model directory under the folder), the answer carries the
    // recorded form as well, the same as predict's file.
    let mut server = ServerProcess::spawn(Path::new(env!("CARGO_BIN_EXE_cnfmp")), dir.path(), &[]).unwrap();
    let base = server.base_url(Duration::from_secs(300)).expect("the server listens within 300 s");
    let encode = |name: &str| base64::engine::general_purpose::STANDARD.encode(std::fs::read(scene.join(name)).unwrap());
    let objects: Value = serde_json::from_slice(&std::fs::read(scene.join("objects.json")).unwrap()).unwrap();
    let request = serde_json::json!({"image_base64": encode("image.png"), "masks_base64": encode("masks.png"), "objects": objects});
    let mut response = http_client()
        .post(format!("{base}/v1/trajectories"))
        .header("Content-Type", "application/json")
        .send(request.to_string().as_bytes())
        .expect("the server answers");
    let status = response.status().as_u16();
    let answer: Value = serde_json::from_str(&response.body_mut().read_to_string().unwrap()).unwrap();
    assert_eq!(status, 200, "{answer}");
    assert_eq!(answer["recorded"], *recorded, "the HTTP answer's recorded frames are predict's");
    assert_eq!(answer["frames"].as_array().unwrap().len(), predicted.frames.len());
    assert!(server.stop(Duration::from_secs(60)), "the server exits 0 on SIGTERM");
}
