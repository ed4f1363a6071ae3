//! An episode as any source reader hands it over, and how reading or staging one can fail.

use segmenter_bridge::SkippedEpisode;

use crate::failure::Failure;
use crate::images::Image;
use crate::trajectory::Trajectory;

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
