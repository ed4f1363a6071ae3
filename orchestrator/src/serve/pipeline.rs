//! The Python work behind `POST /v1/trajectories`, behind a trait: the server queues a
//! [`PipelineJob`] and awaits its [`PipelineResult`]. [`BridgePipeline`] runs batches of jobs
//! for one model on the bridge's worker (segment each prompt, unless the masks came with the
//! request, then predict the batch's scenes together); tests of the HTTP layer stand in a
//! fake, so its 4xx paths need no Python.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use segmenter_bridge::{Bridge, BridgeError, Prediction, ScanLabelling, SceneToPredict, SegmentRequest, Segmentation};
use tokio::sync::oneshot;

use super::error::ApiError;
use super::metrics::QueueGauges;
use super::queue::{Batching, Done, PythonQueue, Refused};
use crate::scene_masks::CoarseMasks;

/// How a request finds its objects.
pub enum SceneObjects {
    /// The segmenter finds the objects the prompt names.
    Prompt(String),
    /// The request carried the coarse masks.
    Masks(CoarseMasks),
    /// The request was a scan or a point cloud (for a model that takes scans).
    Scan(Arc<UploadedScan>),
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

/// A request's scan written to a directory that lives as long as the job: the scan directory
/// itself, or the directory of a point cloud file (`file`).
pub struct UploadedScan {
    pub dir: tempfile::TempDir,
    pub file: Option<&'static str>,
    /// A prompt whose objects the segmenter finds in the views' RGB images, instead of the
    /// scan's label maps.
    pub prompt: Option<String>,
}

impl UploadedScan {
    /// What `cnfmp predict --scan` would be given: the directory, or the cloud file in it.
    pub fn path(&self) -> PathBuf {
        self.file.map_or_else(|| self.dir.path().to_path_buf(), |file| self.dir.path().join(file))
    }
}

/// The coarse masks a request was answered with.
pub enum FoundObjects {
    /// Found by the segmenter from the prompt.
    Segmented(Segmentation),
    /// Sent with the request.
    Given(CoarseMasks),
    /// In the scan's label maps.
    Scanned,
}

/// The result of the Python part of one request.
pub struct PipelineOutput {
    pub found: FoundObjects,
    pub prediction: Prediction,
    /// Seconds spent segmenting (0 when the masks came with the request) and predicting (the
    /// whole batch's prediction: its scenes are predicted together).
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

/// The real pipeline: batches of jobs run in order on the bridge's Python worker.
pub struct BridgePipeline {
    queue: PythonQueue<PipelineJob, PipelineResult>,
    segmenter: SegmenterChoice,
}

impl BridgePipeline {
    /// Starts the dispatcher thread in front of `bridge`; at most `capacity` jobs wait, and
    /// jobs for the same model are batched as `batching` says.
    pub fn start(bridge: &'static Bridge, capacity: usize, batching: Batching, segmenter: SegmenterChoice)
                 -> std::io::Result<Self> {
        let chosen = segmenter.clone();
        let queue = PythonQueue::start(capacity, batching, |job: &PipelineJob| job.model_dir.clone(),
                                       move |jobs| run_batch(bridge, &chosen, jobs))?;
        Ok(BridgePipeline { queue, segmenter })
    }
}

impl Pipeline for BridgePipeline {
    fn submit(&self, job: PipelineJob) -> Result<oneshot::Receiver<Done<PipelineResult>>, Refused> {
        self.queue.submit(job)
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

/// A job whose objects are found: what it predicts from, and how long finding them took.
struct Found {
    scene: SceneToPredict,
    found: FoundObjects,
    segment_s: f64,
}

/// Runs a batch of jobs for one model: the prompts are segmented together (the masks that
/// came with a request are used as they are), then every scene is predicted in one call. One
/// result per job, in order; a job's bad input fails that job alone.
fn run_batch(bridge: &Bridge, segmenter: &SegmenterChoice, jobs: Vec<PipelineJob>) -> Vec<PipelineResult> {
    let Some(model_dir) = jobs.first().map(|job| job.model_dir.clone()) else { return Vec::new() };
    if jobs.iter().any(|job| matches!(job.objects, SceneObjects::Scan(_))) {
        // A model takes scans or images, never both (the routes check): a batch of scans.
        return jobs.into_iter().map(|job| predict_scan(bridge, segmenter, &model_dir, job)).collect();
    }
    let mut scenes = Vec::with_capacity(jobs.len());
    let found: Vec<Result<(FoundObjects, f64), ApiError>> = find_objects(bridge, segmenter, jobs)
        .into_iter()
        .map(|found| {
            let Found { scene, found, segment_s } = found?;
            scenes.push(scene);
            Ok((found, segment_s))
        })
        .collect();
    let infer_started = Instant::now();
    let mut predictions = match bridge.core_predict_batch(&model_dir, scenes) {
        Ok(predictions) => predictions.into_iter(),
        // A job that already failed keeps its own error; the others share the call's.
        Err(err) => return found.into_iter().map(|found| found.and(Err(ApiError::from(err.clone())))).collect(),
    };
    let infer_s = infer_started.elapsed().as_secs_f64();
    found
        .into_iter()
        .map(|found| {
            let (found, segment_s) = found?;
            let prediction = predictions.next().unwrap_or(Err(BridgeError::Protocol("a batch answer is missing".into())))?;
            Ok(PipelineOutput { found, prediction, segment_s, infer_s })
        })
        .collect()
}

/// One scan job: its files predicted by the model that takes scans.
/// With a prompt, the segmenter labels the scan's RGB views (counted in the prediction's time).
fn predict_scan(bridge: &Bridge, segmenter: &SegmenterChoice, model_dir: &std::path::Path, job: PipelineJob) -> PipelineResult {
    let SceneObjects::Scan(scan) = job.objects else {
        return Err(ApiError::internal("an image job in a batch of scans"));
    };
    let labelling = scan.prompt.clone().map(|prompt| ScanLabelling {
        prompt,
        backend: segmenter.backend.clone(),
        weights: segmenter.weights.clone(),
    });
    let started = Instant::now();
    let prediction = bridge.core_predict_scan(model_dir, &scan.path(), None, labelling)?;
    Ok(PipelineOutput { found: FoundObjects::Scanned, prediction, segment_s: 0.0, infer_s: started.elapsed().as_secs_f64() })
}

/// Each job's objects: its masks when they came with the request, else the segmenter's for
/// its prompt (every prompt of the batch in one call; `segment_s` is that call's time).
fn find_objects(bridge: &Bridge, segmenter: &SegmenterChoice, jobs: Vec<PipelineJob>) -> Vec<Result<Found, ApiError>> {
    let requests: Vec<SegmentRequest> = jobs
        .iter()
        .filter_map(|job| match &job.objects {
            SceneObjects::Prompt(prompt) => Some(SegmentRequest {
                image: job.image.clone(),
                prompt: prompt.clone(),
                backend: segmenter.backend.clone(),
                weights: segmenter.weights.clone(),
                roles: job.roles.clone(),
                pictures: false,
            }),
            SceneObjects::Masks(_) | SceneObjects::Scan(_) => None,
        })
        .collect();
    let started = Instant::now();
    let segmented = if requests.is_empty() { Ok(Vec::new()) } else { bridge.segment_batch(requests) };
    let segment_s = started.elapsed().as_secs_f64();
    // When the whole call fails, every prompted job gets its error; jobs with masks go on.
    let (mut segmented, call_error) = match segmented {
        Ok(answers) => (answers.into_iter(), None),
        Err(err) => (Vec::new().into_iter(), Some(err)),
    };
    jobs.into_iter()
        .map(|job| {
            let (masks, objects, found, seconds) = match job.objects {
                SceneObjects::Masks(masks) => (masks.png(), masks.objects.clone(), FoundObjects::Given(masks), 0.0),
                SceneObjects::Scan(_) => return Err(ApiError::internal("a scan job in a batch of images")),
                SceneObjects::Prompt(_) => {
                    let missing = || Err(call_error.clone().unwrap_or_else(|| BridgeError::Protocol("a segmentation is missing".into())));
                    let found = segmented.next().unwrap_or_else(missing)?;
                    (found.labels_png.clone(), found.slot_names.clone(), FoundObjects::Segmented(found), segment_s)
                }
            };
            Ok(Found { scene: SceneToPredict { image: job.image, masks, objects }, found, segment_s: seconds })
        })
        .collect()
}
