//! Raw folders or HDF5 -> LeRobot: each episode is read, checked, resampled and staged in
//! parallel, then lerobot's writer assembles the staged episodes into the dataset.

use std::path::Path;
use std::time::Instant;

use segmenter_bridge::Bridge;
use serde::Serialize;
use serde_json::Value;

use super::episode::{BadEpisode, EpisodeError, SourceEpisode};
use super::job::{ConvertOptions, ConvertReport, Plan, Source, Target, finish_report, no_episode_converted};
use super::staging::{Staging, stage_all};
use super::{hdf5, raw};
use crate::failure::Failure;
use crate::images;
use crate::trajectory::resample::{ResampleTarget, resample};

pub(super) fn to_lerobot(options: &ConvertOptions, start: Instant) -> Result<ConvertReport, Failure> {
    let bridge = Bridge::start_default()?;
    // What is read per episode: a raw folder, or a demo of the HDF5 file as listed.
    enum Reader<'a> {
        Raw(&'a Path),
        Hdf5(&'a Path, segmenter_bridge::Hdf5Listing),
    }
    let (reader, episodes, recorded_fps) = match &options.source {
        Source::Raw(dir) => {
            let names = raw::list_episodes(dir).map_err(Failure::BadInput)?;
            let fps = names.first().and_then(|first| raw::recorded_fps(&dir.join(first)));
            (Reader::Raw(dir), names, fps)
        }
        Source::Hdf5(file) => {
            let listing = bridge.hdf5_demos(file)?;
            let (names, fps) = (listing.demos.clone(), Some(listing.fps));
            (Reader::Hdf5(file, listing), names, fps)
        }
        Source::Lerobot(_) => unreachable!("handled by export"),
    };
    if episodes.is_empty() {
        return Err(Failure::BadInput(format!("{} holds no episodes", options.source.describe())));
    }
    let fps = match options.fps {
        Some(fps) => fps,
        None => {
            let recorded = recorded_fps.ok_or_else(|| Failure::BadInput("the first episode records no fps; pass --fps".into()))?;
            (recorded.round() as u32).max(1)
        }
    };
    let plan = Plan { source: options.source.describe(), to: Target::Lerobot, fps, episodes };
    let staging = Staging::open(&options.out, &plan)?;
    let stage_one = |index: usize, work: &Path| -> Result<(), EpisodeError> {
        let name = &plan.episodes[index];
        let episode = match &reader {
            Reader::Raw(dir) => raw::read_episode(&dir.join(name), name)?,
            Reader::Hdf5(file, listing) => hdf5::read_episode(bridge, file, name, listing)?,
        };
        stage_episode(&episode, fps, work)
    };
    let outcome = stage_all(&staging, &plan, options.workers, options.strict, &stage_one)?;

    let staged = staging.staged_names(&plan);
    if staged.is_empty() {
        return Err(no_episode_converted(&outcome.skipped));
    }
    let dataset = staging.output_dir();
    let written = bridge.write_staged(&staging.episodes_dir(), staged, &dataset, fps)?;
    let mut skipped = outcome.skipped;
    skipped.extend(written.skipped);
    let report = finish_report(options, &plan, outcome.resumed, written.episodes, written.frames, skipped, start);
    staging.publish(&report, &options.out)?;
    Ok(report)
}


/// The staged form of an episode (read by `cnfmp.data.lerobot_io.write_staged`).
#[derive(Serialize)]
struct StagedEpisode<'a> {
    name: &'a str,
    source: &'a str,
    prompt: &'a str,
    task: &'a str,
    seed: i64,
    objects: &'a [String],
    width: u32,
    height: u32,
    /// PNG files in the folder; `frame_images[k]` indexes this list for frame k.
    images: Vec<String>,
    frame_images: Vec<usize>,
    masks: &'static str,
    trajectory: Value,
}

/// Checks `episode`, resamples its trajectory to `fps` and writes the staged files into
/// `work` (an empty folder): the images frames use, `masks.png`, and `episode.json` last.
fn stage_episode(episode: &SourceEpisode, fps: u32, work: &Path) -> Result<(), EpisodeError> {
    let bad = |file: &str, reason: String| EpisodeError::Bad(BadEpisode { episode: episode.name.clone(), file: file.to_owned(), reason });
    let first = &episode.images[0];
    if (episode.masks.width, episode.masks.height) != (first.width, first.height) {
        return Err(bad(&episode.source, format!("the masks are {} but the image is {}; they must have the same size", episode.masks.size(), first.size())));
    }
    let highest = episode.masks.max_label() as usize;
    if highest > episode.objects.len() {
        return Err(bad(&episode.source, format!("unknown object: mask label {highest} has no name ({} object name(s) given)", episode.objects.len())));
    }
    if episode.prompt.trim().is_empty() {
        return Err(bad(&episode.source, "the prompt is empty; every episode needs its language instruction".into()));
    }
    if episode.trajectory.frames.len() < 2 {
        return Err(bad(&episode.source, "the trajectory has one frame; a demonstration needs at least two".into()));
    }
    let trajectory = resample(&episode.trajectory, ResampleTarget::Fps(fps as f64)).map_err(|err| bad(&episode.source, err.to_string()))?;

    // Each resampled frame shows the source image nearest to it in time.
    let frame_sources: Vec<usize> = if episode.images.len() == 1 {
        vec![0; trajectory.frames.len()]
    } else {
        let times: Vec<f64> = episode.trajectory.frames.iter().map(|f| f.t).collect();
        trajectory.frames.iter().map(|frame| nearest(&times, frame.t)).collect()
    };
    let mut used: Vec<usize> = frame_sources.clone();
    used.sort_unstable();
    used.dedup();
    let fatal = |err: String| EpisodeError::Fatal(Failure::Environment(err));
    let mut files = Vec::with_capacity(used.len());
    for &source in &used {
        let file = format!("image_{source:06}.png");
        images::write_png(&work.join(&file), &episode.images[source]).map_err(fatal)?;
        files.push(file);
    }
    images::write_png(&work.join("masks.png"), &episode.masks).map_err(fatal)?;
    let staged = StagedEpisode {
        name: &episode.name,
        source: &episode.source,
        prompt: &episode.prompt,
        task: &episode.task,
        seed: episode.seed.map_or(-1, |seed| seed as i64),
        objects: &episode.objects,
        width: first.width,
        height: first.height,
        images: files,
        frame_images: frame_sources.iter().map(|source| used.binary_search(source).expect("every source is in used")).collect(),
        masks: "masks.png",
        trajectory: serde_json::from_str(&trajectory.to_json_string()).expect("trajectory JSON parses"),
    };
    let text = serde_json::to_string(&staged).expect("staged episode serialises");
    std::fs::write(work.join("episode.json"), text).map_err(|err| fatal(format!("cannot write {}: {err}", work.display())))
}

/// Index of the time in `times` (increasing) nearest to `t`.
fn nearest(times: &[f64], t: f64) -> usize {
    let after = times.partition_point(|&time| time < t);
    if after == 0 {
        0
    } else if after == times.len() || t - times[after - 1] <= times[after] - t {
        after - 1
    } else {
        after
    }
}

#[cfg(test)]
mod tests {
    use super::nearest;

    #[test]
    fn nearest_picks_the_closest_time() {
        let times = [0.0, 0.1, 0.2, 0.3];
        assert_eq!(nearest(&times, -1.0), 0);
        assert_eq!(nearest(&times, 0.14), 1);
        assert_eq!(nearest(&times, 0.16), 2);
        assert_eq!(nearest(&times, 0.3), 3);
        assert_eq!(nearest(&times, 9.0), 3);
    }
}
