//! What a conversion is asked to do (`Source`, `Target`, `ConvertOptions`) and what it reports
//! (`ConvertReport`), shared by both directions.

use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Instant;

use segmenter_bridge::SkippedEpisode;
use serde::{Deserialize, Serialize};

use crate::failure::Failure;


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
    pub(super) fn path(&self) -> &Path {
        match self {
            Source::Raw(path) | Source::Hdf5(path) | Source::Lerobot(path) => path,
        }
    }

    /// `format:absolute-path`, as recorded in the plan and the report.
    pub(super) fn describe(&self) -> String {
        let format = match self {
            Source::Raw(_) => "raw",
            Source::Hdf5(_) => "hdf5",
            Source::Lerobot(_) => "lerobot",
        };
        let path = std::path::absolute(self.path()).unwrap_or_else(|_| self.path().to_path_buf());
        format!("{format}:{}", path.display())
    }
}

/// What a conversion does; stored so that a rerun resumes only the same conversion.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Plan {
    /// `format:absolute-path` of the source.
    pub source: String,
    pub to: Target,
    /// Dataset frame rate (Hz).
    pub fps: u32,
    /// Source episode names, in output order.
    pub episodes: Vec<String>,
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


/// The error when every episode was bad: the first reasons, so the user can fix them.
pub(super) fn no_episode_converted(skipped: &[SkippedEpisode]) -> Failure {
    let reasons: Vec<String> = skipped.iter().take(3).map(|bad| format!("{}: {}: {}", bad.episode, bad.file, bad.reason)).collect();
    Failure::BadInput(format!("no episode could be converted ({} bad); first: {}", skipped.len(), reasons.join("; ")))
}

pub(super) fn finish_report(options: &ConvertOptions, plan: &Plan, resumed: u64, converted: u64, frames: u64, skipped: Vec<SkippedEpisode>, start: Instant) -> ConvertReport {
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

#[cfg(test)]
mod tests {
    use super::Source;

    #[test]
    fn sources_parse() {
        assert_eq!("raw:/a/b".parse::<Source>().unwrap(), Source::Raw("/a/b".into()));
        assert_eq!("hdf5:x.hdf5".parse::<Source>().unwrap(), Source::Hdf5("x.hdf5".into()));
        assert!("zarr:x".parse::<Source>().unwrap_err().contains("unknown format"));
        assert!("raw:".parse::<Source>().unwrap_err().contains("no path"));
        assert!("/just/a/path".parse::<Source>().unwrap_err().contains("FORMAT:PATH"));
    }
}
