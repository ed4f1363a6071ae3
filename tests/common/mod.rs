//! Helpers shared by the end-to-end tests: run the real `cnfmp` binary and read its output.

#![allow(dead_code)] // each test crate uses its own subset

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// Runs `cnfmp ARGS` and waits for it, with one torch thread (the tests run side by side;
/// training would otherwise use every core).
pub fn cnfmp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cnfmp"))
        .args(args)
        .env("CNFMP_TORCH_THREADS", "1")
        .output()
        .expect("the cnfmp binary runs")
}

pub fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

pub fn arg(path: &Path) -> &str {
    path.to_str().unwrap()
}

/// A core configuration small enough to train in seconds (the end-to-end tests check the
/// plumbing, not the model's accuracy).
pub const TINY_CONFIG: &str = r#"{"field_resolution": 32, "latent_dim": 8, "num_endpoints": 3, "field_width": 32,
  "field_layers": 2, "appearance_octaves": 4, "pixels_per_object": 64, "uniform_pixels": 64, "mask_dilation": 2,
  "time_samples": 32, "search_candidates": 16,
  "search_starts": 2, "refine_steps": 5, "inference_pixels": 128, "motion_refit_steps": 20}"#;

/// The repository root.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap().to_path_buf()
}

/// Copies the directory tree `from` to `to` (created).
pub fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.path().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}
