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

pub mod export;
pub mod hdf5;
pub mod raw;
mod staging;
pub mod validate;

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use segmenter_bridge::{Bridge, SkippedEpisode};
use serde::{Deserialize, Serialize};
use serde_json::Value;

use crate::failure::Failure;
use crate::images::{self, Image};
use crate::trajectory::Trajectory;
use crate::trajectory::resample::{ResampleTarget, resample};
pub use staging::Plan;
use staging::{Staging, stage_all};

/// Where demonstrations come from: `raw:DIR`, `hdf5:FILE` or `lerobot:DIR`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Source {
    Raw(PathBuf),
    Hdf5(PathBuf),
    Lerobot(PathBuf),
}

impl FromStr for Source {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, String> {
        let (format, path) = text.split_once(':').ok_or_else(|| format!("`{text}` is not FORMAT:PATH (raw:DIR, hdf5:FILE or lerobot:DIR)"))?;
        if path.is_empty() {
            return Err(format!("`{text}` names no path after `{format}:`"));
        }
        let path = PathBuf::from(path);
        match format {
            "raw" => Ok(Source::Raw(path)),
            "hdf5" => Ok(Source::Hdf5(path)),
            "lerobot" => Ok(Source::Lerobot(path)),
            other => Err(format!("unknown format `{other}`; use raw:DIR, hdf5:FILE or lerobot:DIR")),
        }
    }
}

impl Source {
    fn path(&self) -> &Path {
        match self {
            Source::Raw(path) | Source::Hdf5(path) | Source::Lerobot(path) => path,
        }
    }

    /// `format:absolute-path`, as recorded in the plan and the report.
    fn describe(&self) -> String {
        let format = match self {
            Source::Raw(_) => "raw",
            Source::Hdf5(_) => "hdf5",
            Source::Lerobot(_) => "lerobot",
        };
        let path = std::path::absolute(self.path()).unwrap_or_else(|_| self.path().to_path_buf());
        format!("{format}:{}", path.display())
    }
}

/// The output format of a conversion.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "lowercase")]
pub enum Target {
    /// A LeRobot v3.0 dataset (from raw or hdf5).
    Lerobot,
    /// Raw episode folders (from lerobot).
    Raw,
}

/// Everything `cnfmp dataset convert` was asked to do.
#[derive(Debug, Clone)]
pub struct ConvertOptions {
    pub source: Source,
    pub to: Target,
    pub out: PathBuf,
    /// Dataset frame rate (Hz); None = the source's own rate.
    pub fps: Option<u32>,
    /// Staging worker threads (>= 1).
    pub workers: usize,
    /// Fail on the first bad episode instead of skipping it.
    pub strict: bool,
}

/// The outcome, printed as JSON and stored in the output as `conversion_report.json`.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct ConvertReport {
    pub source: String,
    pub to: Target,
    pub out: String,
    pub fps: f64,
    /// Episodes in the source.
    pub episodes: u64,
    pub converted: u64,
    /// Staged by an earlier, interrupted run and reused.
    pub resumed: u64,
    pub frames: u64,
    /// Bad episodes, each with the file at fault and why; never skipped silently.
    pub skipped: Vec<SkippedEpisode>,
    pub seconds: f64,
    pub episodes_per_second: f64,
}

/// Name of the report inside the output.
pub const REPORT_FILE: &str = "conversion_report.json";

/// An episode as read from any source, before staging.
#[derive(Debug, Clone)]
pub struct SourceEpisode {
    pub name: String,
    /// Where it came from (folder, `file:data/demo_3`), for reports.
    pub source: String,
    pub prompt: String,
    pub task: String,
    pub seed: Option<u64>,
    /// At the source's own times.
    pub trajectory: Trajectory,
    /// One image for the whole episode, or one per trajectory frame (RGB, same size).
    pub images: Vec<Image>,
    /// Label map of the images' size; label k names `objects[k - 1]`.
    pub masks: Image,
    pub objects: Vec<String>,
}

/// Why an episode was left out.
pub type BadEpisode = SkippedEpisode;

/// How staging one episode can fail: the episode is bad (report and go on, or stop under
/// `--strict`), or the conversion cannot go on (disk full, interpreter gone).
#[derive(Debug)]
pub enum EpisodeError {
    Bad(BadEpisode),
    Fatal(Failure),
}

impl From<BadEpisode> for EpisodeError {
    fn from(bad: BadEpisode) -> Self {
        EpisodeError::Bad(bad)
    }
}

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
        (_, Target::Lerobot) => to_lerobot(options, start),
    }
}

fn to_lerobot(options: &ConvertOptions, start: Instant) -> Result<ConvertReport, Failure> {
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

/// The error when every episode was bad: the first reasons, so the user can fix them.
fn no_episode_converted(skipped: &[SkippedEpisode]) -> Failure {
    let reasons: Vec<String> = skipped.iter().take(3).map(|bad| format!("{}: {}: {}", bad.episode, bad.file, bad.reason)).collect();
    Failure::BadInput(format!("no episode could be converted ({} bad); first: {}", skipped.len(), reasons.join("; ")))
}

fn finish_report(options: &ConvertOptions, plan: &Plan, resumed: u64, converted: u64, frames: u64, skipped: Vec<SkippedEpisode>, start: Instant) -> ConvertReport {
    let seconds = start.elapsed().as_secs_f64();
    let out = std::path::absolute(&options.out).unwrap_or_else(|_| options.out.clone());
    ConvertReport {
        source: plan.source.clone(),
        to: plan.to,
        out: out.display().to_string(),
        fps: plan.fps as f64,
        episodes: plan.episodes.len() as u64,
        converted,
        resumed,
        frames,
        skipped,
        seconds,
        episodes_per_second: converted as f64 / seconds.max(1e-9),
    }
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
pub fn stage_episode(episode: &SourceEpisode, fps: u32, work: &Path) -> Result<(), EpisodeError> {
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
    use super::*;

    #[test]
    fn sources_parse() {
        assert_eq!("raw:/a/b".parse::<Source>().unwrap(), Source::Raw("/a/b".into()));
        assert_eq!("hdf5:x.hdf5".parse::<Source>().unwrap(), Source::Hdf5("x.hdf5".into()));
        assert!("zarr:x".parse::<Source>().unwrap_err().contains("unknown format"));
        assert!("raw:".parse::<Source>().unwrap_err().contains("no path"));
        assert!("/just/a/path".parse::<Source>().unwrap_err().contains("FORMAT:PATH"));
    }

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
