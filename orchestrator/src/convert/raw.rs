//! The raw dataset format: one folder per episode, plain files a lab can write from any
//! recorder (README, "Dataset formats"):
//!
//! ```text
//! <episode>/image.png           scene image (RGB; grayscale expanded, alpha dropped)
//! <episode>/frames/*.png        optional: one image per trajectory frame, in name order
//! <episode>/masks.png           label map (0 background, k = k-th name of objects.json) ...
//! <episode>/objects.json        ... with the object names: ["cup", "plate"] or {"objects": [...]}
//! <episode>/masks/<object>.png  ... or one binary mask per object (order: objects.json, else names)
//! <episode>/trajectory.json     trajectory JSON (design.md), or
//! <episode>/trajectory.csv      t,x,y,z,qw,qx,qy,qz,gripper at meta.json's fps
//! <episode>/meta.json           {"task": ..., "prompt": ..., "fps": ..., "seed": optional}
//! ```

use std::path::{Path, PathBuf};

use serde::Deserialize;
use serde_json::Value;

use super::episode::{BadEpisode, SourceEpisode};
use crate::images::{self, Image};
use crate::scene_masks;
use crate::trajectory::{Trajectory, csv};

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct Meta {
    #[serde(default)]
    task: String,
    prompt: String,
    fps: Option<f64>,
    seed: Option<u64>,
}

/// The episode folders under `dir`, in name order (hidden entries and files are ignored).
pub fn list_episodes(dir: &Path) -> Result<Vec<String>, String> {
    let entries = std::fs::read_dir(dir).map_err(|err| format!("cannot read {}: {err}", dir.display()))?;
    let mut names = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|err| format!("cannot read {}: {err}", dir.display()))?;
        let name = entry.file_name().to_string_lossy().into_owned();
        if !name.starts_with('.') && entry.path().is_dir() {
            names.push(name);
        }
    }
    if names.is_empty() && (dir.join("trajectory.json").exists() || dir.join("trajectory.csv").exists()) {
        return Err(format!("{} is one episode folder; pass the folder that contains the episode folders", dir.display()));
    }
    names.sort();
    Ok(names)
}

/// The rate an episode was recorded at (Hz): meta.json's `fps`, else trajectory.json's.
pub fn recorded_fps(episode: &Path) -> Option<f64> {
    let read = |name: &str| -> Option<Value> { serde_json::from_str(&std::fs::read_to_string(episode.join(name)).ok()?).ok() };
    read("meta.json").and_then(|meta| meta["fps"].as_f64()).or_else(|| read("trajectory.json").and_then(|t| t["fps"].as_f64()))
}

/// Reads and checks one episode folder.
pub fn read_episode(dir: &Path, name: &str) -> Result<SourceEpisode, BadEpisode> {
    let bad = |file: &Path, reason: String| BadEpisode { episode: name.to_owned(), file: file.display().to_string(), reason };
    let meta_path = dir.join("meta.json");
    let meta: Meta = match std::fs::read_to_string(&meta_path) {
        Ok(text) => serde_json::from_str(&text).map_err(|err| bad(&meta_path, format!("not a valid meta.json ({{\"task\", \"prompt\", \"fps\"}}): {err}")))?,
        Err(err) => return Err(bad(&meta_path, format!("cannot read: {err}"))),
    };

    let json_path = dir.join("trajectory.json");
    let csv_path = dir.join("trajectory.csv");
    let trajectory = if json_path.exists() {
        let text = std::fs::read_to_string(&json_path).map_err(|err| bad(&json_path, format!("cannot read: {err}")))?;
        Trajectory::from_json_str(&text).map_err(|err| bad(&json_path, err.to_string()))?
    } else if csv_path.exists() {
        let fps = meta.fps.ok_or_else(|| bad(&meta_path, "has no `fps`, which trajectory.csv needs".into()))?;
        let text = std::fs::read_to_string(&csv_path).map_err(|err| bad(&csv_path, format!("cannot read: {err}")))?;
        csv::from_csv_str(&text, fps).map_err(|err| bad(&csv_path, err.to_string()))?
    } else {
        return Err(bad(dir, "no trajectory.json or trajectory.csv".into()));
    };

    let image_path = dir.join("image.png");
    let image = images::read_rgb(&image_path).map_err(|reason| bad(&image_path, reason))?;
    let frames_dir = dir.join("frames");
    let images = if frames_dir.is_dir() {
        let files = png_files(&frames_dir).map_err(|reason| bad(&frames_dir, reason))?;
        if files.len() != trajectory.frames.len() {
            return Err(bad(&frames_dir, format!("holds {} PNG images but the trajectory has {} frames; give one image per frame", files.len(), trajectory.frames.len())));
        }
        let mut frames = Vec::with_capacity(files.len());
        for file in files {
            let frame = images::read_rgb(&file).map_err(|reason| bad(&file, reason))?;
            if (frame.width, frame.height) != (image.width, image.height) {
                return Err(bad(&file, format!("is {} but image.png is {}", frame.size(), image.size())));
            }
            frames.push(frame);
        }
        frames
    } else {
        vec![image]
    };

    let (masks, objects) = read_masks(dir, &images[0]).map_err(|(file, reason)| bad(&file, reason))?;
    Ok(SourceEpisode {
        name: name.to_owned(),
        source: dir.display().to_string(),
        prompt: meta.prompt,
        task: meta.task,
        seed: meta.seed,
        trajectory,
        images,
        masks,
        objects,
    })
}

fn png_files(dir: &Path) -> Result<Vec<PathBuf>, String> {
    let entries = std::fs::read_dir(dir).map_err(|err| format!("cannot read: {err}"))?;
    let mut files: Vec<PathBuf> = entries
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|path| path.extension().is_some_and(|ext| ext.eq_ignore_ascii_case("png")))
        .collect();
    files.sort();
    Ok(files)
}

fn read_objects(path: &Path) -> Result<Vec<String>, String> {
    let text = std::fs::read(path).map_err(|err| format!("cannot read: {err}"))?;
    scene_masks::parse_objects_text(&text).map_err(|err| err.message)
}

/// The label map and object names, from masks.png + objects.json or masks/<object>.png.
fn read_masks(dir: &Path, image: &Image) -> Result<(Image, Vec<String>), (PathBuf, String)> {
    let objects_path = dir.join("objects.json");
    let objects = if objects_path.exists() { Some(read_objects(&objects_path).map_err(|reason| (objects_path.clone(), reason))?) } else { None };
    let check_size = |path: &Path, mask: &Image| {
        if (mask.width, mask.height) == (image.width, image.height) {
            Ok(())
        } else {
            Err((path.to_path_buf(), format!("the mask is {} but the image is {}; they must have the same size", mask.size(), image.size())))
        }
    };

    let label_path = dir.join("masks.png");
    if label_path.exists() {
        let objects = objects.ok_or_else(|| (objects_path.clone(), "missing: masks.png needs objects.json to name its labels".to_owned()))?;
        let labels = images::read_label_map(&label_path).map_err(|reason| (label_path.clone(), reason))?;
        check_size(&label_path, &labels)?;
        let highest = labels.max_label() as usize;
        if highest > objects.len() {
            return Err((label_path, format!("unknown object: label {highest} has no name (objects.json names {} object(s))", objects.len())));
        }
        return Ok((labels, objects));
    }

    let masks_dir = dir.join("masks");
    if !masks_dir.is_dir() {
        return Err((dir.to_path_buf(), "no masks: expected masks.png + objects.json, or masks/<object>.png".into()));
    }
    let files = png_files(&masks_dir).map_err(|reason| (masks_dir.clone(), reason))?;
    let stem = |path: &PathBuf| path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let objects = match objects {
        Some(objects) => {
            if let Some(unknown) = files.iter().find(|file| !objects.contains(&stem(file))) {
                return Err((unknown.clone(), format!("unknown object `{}`: objects.json names {}", stem(unknown), objects.join(", "))));
            }
            objects
        }
        None => files.iter().map(stem).collect(),
    };
    if objects.len() > 255 {
        return Err((masks_dir, format!("{} objects; a label map holds at most 255", objects.len())));
    }
    let mut labels = Image { width: image.width, height: image.height, channels: 1, pixels: vec![0; image.pixels.len() / 3] };
    for (k, object) in objects.iter().enumerate() {
        let path = masks_dir.join(format!("{object}.png"));
        if !path.exists() {
            return Err((path, format!("missing: objects.json names `{object}` but it has no mask")));
        }
        let mask = images::read_label_map(&path).map_err(|reason| (path.clone(), reason))?;
        check_size(&path, &mask)?;
        // Painter's order: where coarse masks overlap, the later object wins.
        for (label, &value) in labels.pixels.iter_mut().zip(&mask.pixels) {
            if value != 0 {
                *label = (k + 1) as u8;
            }
        }
    }
    Ok((labels, objects))
}
