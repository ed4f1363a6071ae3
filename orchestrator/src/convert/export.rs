//! `cnfmp dataset convert --from lerobot:DIR --to raw`: a LeRobot dataset as raw episode
//! folders, so converted data can be inspected with ordinary tools and round-tripped.
//! lerobot reads the episodes (through the bridge, one at a time); trajectories are checked
//! and written by the Rust trajectory code, like every other trajectory file.

use std::path::Path;
use std::time::Instant;

use segmenter_bridge::{Bridge, BridgeError};
use serde_json::Map;

use super::staging::{Staging, stage_all};
use super::episode::{BadEpisode, EpisodeError};
use super::job::{ConvertOptions, ConvertReport, Plan, Target, finish_report, no_episode_converted};
use crate::failure::Failure;
use crate::trajectory::Trajectory;

pub(super) fn export(options: &ConvertOptions, start: Instant) -> Result<ConvertReport, Failure> {
    let bridge = Bridge::start_default()?;
    let dataset = options.source.path();
    let episodes = bridge.dataset_episodes(dataset)?;
    if let Some(fps) = options.fps
        && (fps as f64 - episodes.fps).abs() > 1e-9
    {
        return Err(Failure::BadInput(format!("--fps {fps} differs from the dataset's {} fps; an export keeps the dataset's frames as they are", episodes.fps)));
    }
    let plan = Plan { source: options.source.describe(), to: Target::Raw, fps: episodes.fps.round() as u32, episodes: episodes.names.clone() };
    let staging = Staging::open(&options.out, &plan)?;
    let stage_one = |index: usize, work: &Path| -> Result<(), EpisodeError> {
        let bad = |reason: String| EpisodeError::Bad(BadEpisode { episode: plan.episodes[index].clone(), file: format!("{}#episode{index}", dataset.display()), reason });
        // The bridge creates the folder itself.
        std::fs::remove_dir(work).map_err(|err| EpisodeError::Fatal(Failure::Environment(format!("cannot prepare {}: {err}", work.display()))))?;
        let arrays = match bridge.export_episode(dataset, index as u64, work) {
            Ok(arrays) => arrays,
            Err(BridgeError::InvalidInput(reason)) => return Err(bad(reason)),
            Err(other) => return Err(EpisodeError::Fatal(other.into())),
        };
        let trajectory = Trajectory::from_arrays(&arrays, Map::new()).map_err(|err| bad(format!("observation.state {err}")))?;
        std::fs::write(work.join("trajectory.json"), trajectory.to_json_string())
            .map_err(|err| EpisodeError::Fatal(Failure::Environment(format!("cannot write {}: {err}", work.display()))))
    };
    let outcome = stage_all(&staging, &plan, options.workers, options.strict, &stage_one)?;
    let moved = staging.move_staged_to_output(&plan)?;
    if moved.is_empty() {
        return Err(no_episode_converted(&outcome.skipped));
    }
    let frames = moved.iter().map(|&k| episodes.lengths[k]).sum();
    let converted = moved.len() as u64;
    let report = finish_report(options, &plan, outcome.resumed, converted, frames, outcome.skipped, start);
    staging.publish(&report, &options.out)?;
    Ok(report)
}
