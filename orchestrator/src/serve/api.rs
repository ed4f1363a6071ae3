//! The HTTP API's request and response documents. They are the contract with clients: the
//! OpenAPI description (`GET /openapi.json`) is generated from these types, and they are
//! built from the bridge's types rather than exposing them, so the wire format stays stable
//! when the Python side changes.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use utoipa::ToSchema;

/// `POST /v1/trajectories` as JSON.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct TrajectoryJsonRequest {
    /// The scene image (PNG, JPEG, BMP, ...), base64-encoded (standard alphabet, padding optional).
    #[schema(min_length = 1)]
    pub image_base64: String,
    /// What to do, naming the objects, e.g. "put the green cube on the paper". Needed unless
    /// the coarse masks come with the request.
    #[serde(default)]
    #[schema(min_length = 1, max_length = 1000, example = "put the green cube on the paper")]
    pub prompt: Option<String>,
    /// The coarse masks instead of the segmenter's: an 8-bit label map PNG of the image's size
    /// (0 background, k the k-th object, in the model's slot order), base64. Needs `objects`.
    #[serde(default)]
    pub masks_base64: Option<String>,
    /// The names of the labelled objects, in label order (as `objects.json`).
    #[serde(default)]
    #[schema(example = json!(["block", "tray"]))]
    pub objects: Option<Vec<String>>,
    /// Use the served model trained on this task (see `GET /v1/models`).
    #[serde(default)]
    #[schema(example = "language_pick_place")]
    pub task: Option<String>,
    /// Use this served model by name (overrides `task`).
    #[serde(default)]
    #[schema(example = "language_pick_place")]
    pub model: Option<String>,
    /// Also return the coarse masks the segmenter found, as a label map PNG.
    #[serde(default)]
    pub include_masks: Option<bool>,
}

/// `POST /v1/trajectories` as `multipart/form-data` (the same fields; the image as a file).
#[derive(Debug, Clone, ToSchema)]
#[allow(dead_code)] // documents the form for the OpenAPI description; the form is parsed field by field
pub struct TrajectoryForm {
    /// The scene image file (PNG, JPEG, BMP, ...).
    #[schema(value_type = String, format = Binary)]
    pub image: Vec<u8>,
    /// What to do, naming the objects. Needed unless `masks` and `objects` are sent.
    #[schema(min_length = 1, max_length = 1000, example = "put the green cube on the paper")]
    pub prompt: Option<String>,
    /// The coarse masks instead of the segmenter's: an 8-bit label map PNG of the image's size
    /// (0 background, k the k-th object, in the model's slot order).
    #[schema(value_type = Option<String>, format = Binary)]
    pub masks: Option<Vec<u8>>,
    /// The names of the labelled objects in label order, as a JSON list: `["block", "tray"]`.
    #[schema(example = "[\"block\", \"tray\"]")]
    pub objects: Option<String>,
    /// Use the served model trained on this task.
    #[schema(example = "language_pick_place")]
    pub task: Option<String>,
    /// Use this served model by name (overrides `task`).
    #[schema(example = "language_pick_place")]
    pub model: Option<String>,
    /// "true" to also return the coarse masks as a label map PNG.
    pub include_masks: Option<bool>,
}

/// `POST /v1/scan-trajectories` as `multipart/form-data`: a scan, as `cnfmp predict --scan`
/// reads it from a directory: `cameras`, and every file cameras.json names as a further form
/// file whose field name is that file name (e.g. `front_depth.png`: a 16-bit PNG in
/// millimetres, or `.npy` in metres; `front_labels.png`: an 8-bit label map).
#[derive(Debug, Clone, ToSchema)]
#[allow(dead_code)] // documents the form for the OpenAPI description; the form is parsed field by field
pub struct ScanTrajectoryForm {
    /// The scan's cameras.json: `{"objects": [names in label order], "depth_unit": "mm",
    /// "views": [{"name", "width", "height", "intrinsics": 3x3, "world_from_camera": 4x4
    /// (OpenCV camera axes, metres), "depth", "labels", "rgb" (optional): file names}]}`.
    #[schema(value_type = Option<String>, format = Binary)]
    pub cameras: Option<Vec<u8>>,
    /// Instead of a scan: a labelled point cloud with its sensor origins (.npz: points,
    /// labels, origins, view; .ply: vertex x y z label view and an origin element).
    #[schema(value_type = Option<String>, format = Binary)]
    pub cloud: Option<Vec<u8>>,
    /// Find the objects with the segmenter on the views' RGB images (a model with prompt
    /// roles) instead of the label maps.
    #[schema(min_length = 1, max_length = 1000)]
    pub prompt: Option<String>,
    /// Use the served model trained on this task.
    #[schema(example = "drawer_place")]
    pub task: Option<String>,
    /// Use this served model by name (overrides `task`).
    #[schema(example = "drawer_place")]
    pub model: Option<String>,
}

/// One time step of the trajectory (design.md's trajectory JSON).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Frame {
    /// Time since the start (s).
    pub t: f64,
    /// Tool centre point (m, world frame).
    pub position: [f64; 3],
    /// Unit quaternion [w, x, y, z].
    pub orientation: [f64; 4],
    /// Gripper opening in [0, 1], 1 = open.
    pub gripper: f64,
}

/// One time step of a joint-space model's trajectory.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct JointFrame {
    /// Time since the start (s).
    pub t: f64,
    /// One value per name of the answer's `joint_names`, in the recording's units (e.g. rad).
    pub joints: Vec<f64>,
    /// Gripper opening in [0, 1], 1 = open.
    pub gripper: f64,
}

/// The trajectory's frames: end-effector poses, or joint values for a model trained on a
/// joint-space recording (the answer then names the joints in `joint_names`).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
#[serde(untagged)]
pub enum Frames {
    Pose(Vec<Frame>),
    Joints(Vec<JointFrame>),
}

/// The model that answered.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelRef {
    pub name: String,
    pub task: String,
    #[serde(rename = "type")]
    pub model_type: String,
}

/// How well the model's scene field explains an object: the confidence signal of paper
/// §II-C (lower reconstruction error = more confident).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Confidence {
    /// Reconstruction MSE of the object's masked region (RGB in [0, 1]).
    pub reconstruction_mse: Option<f64>,
    /// The same as PSNR (dB).
    pub psnr_db: Option<f64>,
    /// IoU of the model's learned mask with the segmenter's coarse mask.
    pub mask_iou: Option<f64>,
}

/// One object phrase of the prompt (or one named object of the request's masks): what the
/// segmenter found and, for the objects that fill the model's object slots, what the model
/// inferred.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct DetectedObject {
    /// The phrase as parsed from the prompt ("green cube"), or the object's given name.
    pub phrase: String,
    /// target | destination | obstacle | object | unknown.
    pub role: String,
    /// The object has mask pixels.
    pub found: bool,
    /// Mean mask probability in [0, 1] (the peak probability when nothing was found); 1 for
    /// masks sent with the request.
    pub score: f64,
    /// Mask area (px).
    pub area: u64,
    /// [x0, y0, x1, y1) (px).
    pub bbox: Option<[u32; 4]>,
    /// [x, y] (px).
    pub centroid: Option<[f64; 2]>,
    /// The model's object slot this phrase fills (1-based), if any.
    pub slot: Option<u32>,
    /// Inferred simplex weights over the slot's endpoint latents.
    pub latent_weights: Option<Vec<f64>>,
    pub confidence: Option<Confidence>,
}

/// Wall time of each stage (ms).
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct StageTimings {
    /// Waiting for the Python worker.
    pub queue_ms: f64,
    /// Prompt -> coarse masks (language segmenter); 0 when the masks came with the request.
    pub segment_ms: f64,
    /// Latent inference and trajectory decoding (NF-MP core).
    pub infer_ms: f64,
    /// Whole request, from the first byte read to the response.
    pub total_ms: f64,
    /// Requests served together in this one's batch, itself included (1: it ran alone); the
    /// segment and infer times are the batch's.
    pub batch_size: u32,
}

/// The answer to `POST /v1/trajectories`: the trajectory JSON of design.md (`fps`,
/// `frames`) plus what was found and inferred.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct TrajectoryResponse {
    /// Nominal sampling rate (Hz).
    pub fps: f64,
    /// For a joint-space model: the joints of each frame's `joints`, as its recording names
    /// them; absent for an end-effector model.
    #[serde(skip_serializing_if = "Option::is_none", default)]
    pub joint_names: Option<Vec<String>>,
    pub frames: Frames,
    pub model: ModelRef,
    /// The request's prompt, if it had one.
    pub prompt: Option<String>,
    /// The segmenter backend that found the objects; null when the masks came with the request.
    pub segmenter: Option<String>,
    pub objects: Vec<DetectedObject>,
    /// Whole-image reconstruction PSNR (dB) of the model's scene field.
    pub scene_psnr_db: Option<f64>,
    pub timings_ms: StageTimings,
    /// With `include_masks`: an 8-bit label map PNG (label k = the model's k-th slot, or the
    /// request's k-th object), base64.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub masks_png_base64: Option<String>,
    /// For a model trained on a recording in another form (a rotation vector or Euler
    /// angles, a gripper in its own units): the same frames in that form.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub recorded: Option<RecordedFrames>,
}

/// The trajectory in the form the model's training recording used.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct RecordedFrames {
    /// The recording's feature (`action` or `observation.state`).
    pub source: String,
    /// Dimension names, in the recording's order, e.g. `["ee.x", "ee.y", "ee.z", "ee.rx", "ee.ry", "ee.rz", "gripper.pos"]`.
    pub names: Vec<String>,
    /// One row per frame (the frames of `frames`), one value per name.
    pub values: Vec<Vec<f64>>,
}

/// One served model.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelSummary {
    /// Directory name under the models directory; what requests pass as `model`.
    pub name: String,
    pub task: String,
    #[serde(rename = "type")]
    pub model_type: String,
    /// Object slot names of the training scenes, in slot order.
    pub objects: Vec<String>,
    /// The prompt role filling each slot; null when prompts cannot drive this task yet.
    pub roles: Option<Vec<String>>,
    /// What a request may give to find the objects: "prompt" (when there are roles) and
    /// "masks" (`masks` + `objects`, labels in the slot order of `objects` above), for a
    /// model of images; "scan" (`POST /v1/scan-trajectories`) for a model of scans.
    pub inputs: Vec<String>,
    /// Network parameters.
    pub parameters: u64,
    /// Rate (Hz) and length (s) of the trajectories it produces.
    pub output_fps: f64,
    pub duration_s: f64,
    /// Used when a request names neither a model nor a task.
    pub default: bool,
    /// The model card's summary table (dataset, steps, wall time, ...).
    pub card: BTreeMap<String, String>,
}

/// `GET /v1/models`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ModelList {
    pub models: Vec<ModelSummary>,
}

/// `GET /v1/health`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct Health {
    /// Always "ok" when the server answers.
    pub status: String,
    /// Always true when the server answers: it listens only once every model is loaded and
    /// has predicted once, and the segmenter has run once on the vocabulary's phrases, so
    /// its first request is as fast as the later ones.
    pub ready: bool,
    /// Seconds from the process's start until it was ready and listening.
    pub ready_after_s: f64,
    pub version: String,
    /// Models loaded and served.
    pub models: usize,
    /// The segmenter backend in use.
    pub segmenter: String,
    /// Requests waiting for the Python worker, and how many may wait.
    pub queue_depth: usize,
    pub queue_capacity: usize,
    pub uptime_s: f64,
}

/// What went wrong.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ErrorDetail {
    /// A stable machine-readable code (`invalid_image`, `empty_prompt`, `overloaded`, ...).
    pub code: String,
    /// What is wrong and how to fix it.
    pub message: String,
}

/// Every error answer: `{"error": {"code", "message"}}`.
#[derive(Debug, Clone, Serialize, Deserialize, ToSchema)]
pub struct ErrorResponse {
    pub error: ErrorDetail,
}
