//! `cnfmp dataset convert`: batch conversion of recorded demonstrations into LeRobot v3.0
//! datasets (from the raw folder layout or robomimic-style HDF5), and out again (`--to raw`).
//!
//! Two phases, so a conversion can be interrupted at any moment and rerun:
//!
//! 1. **Staging**, in parallel worker threads: each source episode is read, checked
//!    (images, masks, objects, trajectory), its trajectory resampled to the dataset fps, and
//!    written as a staged episode folder; the folder is renamed into place only when
//!    complete. A rerun skips every staged episode, so it continues where the last run stopped.
//! 2. **Writing**: lerobot's writer assembles the staged episodes, in source order, into a
//!    dataset inside the staging area, which is renamed to `--out` only when finalized.
//!
//! The staging area is the hidden folder `.<out name>.convert` beside `--out`; it holds a
//! `plan.json` (source, fps, episode list) so a rerun with different arguments is refused
//! instead of mixing two conversions. Memory is bounded by one episode per worker.


mod episode;
pub mod export;
pub mod hdf5;
mod import;
mod job;
pub mod raw;
mod staging;
pub mod validate;

use std::time::Instant;

pub use episode::{BadEpisode, EpisodeError, SourceEpisode};
pub use job::{ConvertOptions, ConvertReport, Plan, REPORT_FILE, Source, Target};

use crate::failure::Failure;

/// Runs a conversion and returns its report. `--out` must not exist; a staging area left by
/// an interrupted run of the same conversion is resumed.
pub fn convert(options: &ConvertOptions) -> Result<ConvertReport, Failure> {
    let start = Instant::now();
    if options.out.exists() {
        return Err(Failure::BadInput(format!("{} already exists; datasets are never overwritten, choose a new --out", options.out.display())));
    }
    if !options.source.path().exists() {
        return Err(Failure::BadInput(format!("{}: no such file or directory", options.source.path().display())));
    }
    match (&options.source, options.to) {
        (Source::Lerobot(_), Target::Raw) => export::export(options, start),
        (Source::Lerobot(_), Target::Lerobot) => Err(Failure::BadInput("lerobot:DIR is already a LeRobot dataset; use --to raw to export it as raw episode folders".into())),
        (_, Target::Raw) => Err(Failure::BadInput("--to raw exports a LeRobot dataset; use --from lerobot:DIR".into())),
        (_, Target::Lerobot) => import::to_lerobot(options, start),
    }
}
