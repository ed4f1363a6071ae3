//! One module per top-level `cnfmp` subcommand, each exposing its entry point, and the pieces
//! several of them share: `scenes` (batch inputs), `shared` (the command line, a prediction's
//! trajectory), `stats` (summary statistics).

pub mod benchmark;
pub mod dataset;
pub mod demo;
pub mod doctor;
pub mod model;
pub mod predict;
pub mod scenes;
pub mod segment;
pub mod shared;
pub mod stats;
pub mod sim;
pub mod trajectory;

use std::io::{ErrorKind, Write};

use crate::failure::Failure;

/// Writes `text` and a newline to stdout. A closed pipe (`cnfmp ... | head`) is not an error.
pub fn print_stdout(text: &str) -> Result<(), Failure> {
    let mut out = std::io::stdout().lock();
    match writeln!(out, "{text}").and_then(|()| out.flush()) {
        Err(err) if err.kind() != ErrorKind::BrokenPipe => Err(Failure::Environment(format!("cannot write to stdout: {err}"))),
        _ => Ok(()),
    }
}
