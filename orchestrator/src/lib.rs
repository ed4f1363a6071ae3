//! # cnfmp orchestrator
//!
//! The Rust side of cnfmp: it owns the process, the command line, input validation and
//! trajectory post-processing, and reaches the Python numerics only through
//! [`segmenter_bridge`]. The library holds everything the `cnfmp` binary (src/main.rs) runs,
//! so integration tests can use it directly.

pub mod commands;
pub mod convert;
pub mod episode;
pub mod failure;
pub mod files;
pub mod helpers;
pub mod images;
pub mod model_dir;
pub mod progress;
pub mod scene_masks;
pub mod seeds;
pub mod segmentation;
pub mod serve;
pub mod trajectory;
