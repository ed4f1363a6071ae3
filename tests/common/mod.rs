//! Helpers shared by the end-to-end tests: run the real `cnfmp` binary and read its output.

#![allow(dead_code)] // each test crate uses its own subset

use std::path::Path;
use std::process::{Command, Output};

/// Runs `cnfmp ARGS` and waits for it.
pub fn cnfmp(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_cnfmp")).args(args).output().expect("the cnfmp binary runs")
}

pub fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

pub fn arg(path: &Path) -> &str {
    path.to_str().unwrap()
}
