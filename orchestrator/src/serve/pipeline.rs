//! The Python work behind `POST /v1/trajectories`, behind a trait: the server queues a
//! [`PipelineJob`] and awaits its [`PipelineResult`]. [`BridgePipeline`] runs it on the
//! bridge's worker (segment, unless the masks came with the request, then predict); tests of
//! the HTTP layer stand in a fake, so its 4xx paths need no Python.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use segmenter_bridge::{Bridge, Prediction, SegmentRequest, Segmentation};
use tokio::sync::oneshot;

use super::error::ApiError;
use super::metrics::QueueGauges;
use super::queue::{Done, PythonQueue, Refused};
use crate::scene_masks::CoarseMasks;

/// How a request finds its objects.
pub enum SceneObjects {
    /// The segmenter finds the objects the prompt names.
    Prompt(String),
    /// The request carried the coarse masks.
    Masks(CoarseMasks),
}

/// The Python work of one trajectory request.
pub struct PipelineJob {
    /// The served model's directory, and the prompt role of each of its object slots (used
    /// when the objects come from a prompt).
    pub model_dir: PathBuf,
    pub roles: Option<Vec<String>>,
    /// The scene image as sent (PNG, JPEG, ...).
    pub image: Vec<u8>,
    pub objects: SceneObjects,
}

/// The coarse masks a request was answered with.
pub enum FoundObjects {
    /// Found by the segmenter from the prompt.
    Segmented(Segmentation),
    /// Sent with the request.
    Given(CoarseMasks),
}

/// The result of the Python part of one request.
pub struct PipelineOutput {
    pub found: FoundObjects,
    pub prediction: Prediction,
    /// Seconds spent segmenting (0 when the masks came with the request) and predicting.
    pub segment_s: f64,
    pub infer_s: f64,
}

pub type PipelineResult = Result<PipelineOutput, ApiError>;

/// Where the server sends trajectory jobs: a bounded queue in front of a worker.
pub trait Pipeline: Send + Sync {
    /// Queues `job`, or refuses it at once (queue full, shutting down). Dropping the receiver
    /// before the job's turn cancels it.
    fn submit(&self, job: PipelineJob) -> Result<oneshot::Receiver<Done<PipelineResult>>, Refused>;
    /// Jobs waiting, the most that may wait, and jobs waiting or running.
    fn gauges(&self) -> QueueGauges;
    /// The segmenter backend that grounds prompts (for `/v1/health`).
    fn segmenter(&self) -> &str;
    /// Waits (up to `limit`) until no job runs or waits; whether that happened.
    fn wait_idle(&self, limit: Duration) -> bool;
}

/// Which segmenter backend the pipeline uses.
#[derive(Debug, Clone)]
pub struct SegmenterChoice {
    pub backend: String,
    pub weights: Option<PathBuf>,
}

/// The real pipeline: jobs run in order on the bridge's Python worker.
pub struct BridgePipeline {
    queue: PythonQueue<PipelineResult>,
    segmenter: SegmenterChoice,
}

impl BridgePipeline {
    /// Starts the dispatcher thread in front of `bridge`; at most `capacity` jobs wait.
    pub fn start(bridge: &'static Bridge, capacity: usize, segmenter: SegmenterChoice) -> std::io::Result<Self> {
        Ok(BridgePipeline { queue: PythonQueue::start(bridge, capacity)?, segmenter })
    }
}

impl Pipeline for BridgePipeline {
    fn submit(&self, job: PipelineJob) -> Result<oneshot::Receiver<Done<PipelineResult>>, Refused> {
        let segmenter = self.segmenter.clone();
        self.queue.submit(move |bridge| run(bridge, &segmenter, job))
    }

    fn gauges(&self) -> QueueGauges {
        QueueGauges { depth: self.queue.depth(), capacity: self.queue.capacity(), pending: self.queue.pending() }
    }

    fn segmenter(&self) -> &str {
        &self.segmenter.backend
    }

    fn wait_idle(&self, limit: Duration) -> bool {
        self.queue.wait_idle(limit)
    }
}

/// Segments (unless the masks came with the request), then predicts.
fn run(bridge: &Bridge, segmenter: &SegmenterChoice, job: PipelineJob) -> PipelineResult {
    let segment_started = Instant::now();
    let (labels_png, names, found) = match job.objects {
        SceneObjects::Masks(masks) => (masks.png(), masks.objects.clone(), FoundObjects::Given(masks)),
        SceneObjects::Prompt(prompt) => {
            let found = bridge.segment(SegmentRequest {
                image: job.image.clone(),
                prompt,
                backend: segmenter.backend.clone(),
                weights: segmenter.weights.clone(),
                roles: job.roles,
                pictures: false,
            })?;
            (found.labels_png.clone(), found.slot_names.clone(), FoundObjects::Segmented(found))
        }
    };
    let segment_s = match found {
        FoundObjects::Segmented(_) => segment_started.elapsed().as_secs_f64(),
        FoundObjects::Given(_) => 0.0,
    };
    let infer_started = Instant::now();
    let prediction = bridge.core_predict(&job.model_dir, job.image, labels_png, names)?;
    Ok(PipelineOutput { found, prediction, segment_s, infer_s: infer_started.elapsed().as_secs_f64() })
}
