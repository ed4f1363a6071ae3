//! The HTTP routes: typed handlers, the request parsing and checks that run before any
//! Python work is queued, the prompt -> segmenter -> core pipeline, and the OpenAPI
//! description generated from the handlers' annotations.

use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::body::Bytes;
use axum::extract::{DefaultBodyLimit, FromRequest, MatchedPath, Multipart, Request, State};
use axum::http::{HeaderMap, HeaderValue, StatusCode, header};
use axum::middleware::{self, Next};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use base64::Engine;
use base64::engine::{DecodePaddingMode, GeneralPurpose, GeneralPurposeConfig};
use utoipa::OpenApi;

use super::api::*;
use super::catalog::{Catalog, ServedModel};
use super::error::{ApiError, ErrorCode, InternalDetail, REQUEST_ID, request_id};
use super::metrics::Metrics;
use super::pipeline::{FoundObjects, Pipeline, PipelineJob, PipelineOutput, SceneObjects, UploadedScan};
use segmenter_bridge::Prediction;
use super::queue::Refused;
use crate::scene_masks::{self, CoarseMasks, MaskError};
use crate::trajectory::joints::Predicted;

/// What the server accepts; requests beyond get a 4xx before any work is queued.
#[derive(Debug, Clone)]
pub struct Limits {
    /// Largest request body (bytes).
    pub max_body_bytes: usize,
    /// Largest image side (px).
    pub max_image_side: u32,
    /// Longest prompt (characters).
    pub max_prompt_chars: usize,
    /// Longest a request may take, queueing included.
    pub request_timeout: Duration,
}

/// Everything the handlers share.
pub struct AppState {
    pub catalog: Catalog,
    /// Where trajectory jobs go (the Python worker, or a test's stand-in).
    pub pipeline: Box<dyn Pipeline>,
    pub metrics: Metrics,
    pub limits: Limits,
    /// When the process started, and how long it took to be ready (models loaded and warm).
    pub started: Instant,
    pub ready_after: Duration,
}

type Shared = Arc<AppState>;

/// The router with every route, the metrics/access-log middleware and JSON fallbacks.
pub fn router(state: Shared) -> Router {
    let body_limit = state.limits.max_body_bytes;
    Router::new()
        .route("/v1/trajectories", post(create_trajectory))
        .route("/v1/scan-trajectories", post(create_scan_trajectory))
        .route("/v1/health", get(health))
        .route("/v1/models", get(list_models))
        .route("/metrics", get(metrics))
        .route("/openapi.json", get(openapi_json))
        .fallback(unknown_route)
        .method_not_allowed_fallback(method_not_allowed)
        .layer(DefaultBodyLimit::max(body_limit))
        .layer(middleware::from_fn_with_state(Arc::clone(&state), observe))
        .with_state(state)
}

/// Gives every request an id (the client's `x-request-id` when it is a sane token), counts
/// every answer by route, status and error code, and logs one line per request. This is the
/// one place errors are logged: an internal error's details go to the log under the request
/// id, which is all the client sees of them.
async fn observe(State(state): State<Shared>, request: Request, next: Next) -> Response {
    let route = request
        .extensions()
        .get::<MatchedPath>()
        .map(|path| path.as_str().to_owned())
        .unwrap_or_else(|| "unmatched".to_owned());
    let (method, path) = (request.method().clone(), request.uri().path().to_owned());
    let id = request_id(request.headers().get(REQUEST_ID_HEADER));
    let started = Instant::now();
    let mut response = REQUEST_ID.scope(id.clone(), next.run(request)).await;
    let seconds = started.elapsed().as_secs_f64();
    let code = response.extensions().get::<ErrorCode>().map(|code| code.0);
    state.metrics.record_request(&route, response.status().as_u16(), code, seconds);
    eprintln!(
        "{method} {path} {} {:.1} ms{} [{id}]",
        response.status().as_u16(),
        seconds * 1e3,
        code.map(|code| format!(" ({code})")).unwrap_or_default()
    );
    if let Some(InternalDetail(detail)) = response.extensions_mut().remove::<InternalDetail>() {
        eprintln!("cnfmp serve: request {id}: internal error: {detail}");
    }
    if let Ok(value) = HeaderValue::from_str(&id) {
        response.headers_mut().insert(REQUEST_ID_HEADER, value);
    }
    response
}

/// The header that carries a request's id, both ways.
const REQUEST_ID_HEADER: &str = "x-request-id";

async fn unknown_route() -> ApiError {
    ApiError::not_found("unknown_route", "no such route; see GET /openapi.json for the API")
}

async fn method_not_allowed() -> ApiError {
    ApiError::new(StatusCode::METHOD_NOT_ALLOWED, "method_not_allowed", "this route does not accept that method; see GET /openapi.json")
}

/// A trajectory request, whichever way it came.
struct TrajectoryInput {
    image: Vec<u8>,
    prompt: Option<String>,
    /// A label map PNG and the names of its labels.
    masks: Option<Vec<u8>>,
    objects: Option<Vec<String>>,
    task: Option<String>,
    model: Option<String>,
    include_masks: bool,
}

/// Predict a trajectory from a scene image and a prompt, or the image and its coarse masks.
///
/// The prompt names the objects; the language segmenter finds them in the image, the
/// phrases fill the model's object slots by role (e.g. target, destination), and the NF-MP
/// core infers one latent per object and decodes the motion. A client with its own
/// segmentation sends the masks (a label map PNG) and the object names instead, as
/// `cnfmp predict --masks --objects` takes them: every served model accepts those.
#[utoipa::path(
    post,
    path = "/v1/trajectories",
    request_body(
        description = "The scene image and the prompt (or the coarse masks and object names), as a form or as JSON.",
        content(
            (TrajectoryForm = "multipart/form-data"),
            (TrajectoryJsonRequest = "application/json"),
        )
    ),
    responses(
        (status = 200, description = "The trajectory, the objects found and inferred, and stage timings.", body = TrajectoryResponse),
        (status = 400, description = "Malformed request: bad JSON or form, missing field, empty or overlong prompt, not an image; masks that are not a label map PNG of the image's size, labels without a name, more objects than the model's slots.", body = ErrorResponse),
        (status = 404, description = "Unknown model or task.", body = ErrorResponse),
        (status = 413, description = "The body or the image is too large.", body = ErrorResponse),
        (status = 415, description = "Neither multipart/form-data nor application/json.", body = ErrorResponse),
        (status = 422, description = "The prompt cannot drive the model: its objects have no prompt roles, or a needed object is not named or not found in the image. Send the masks instead.", body = ErrorResponse),
        (status = 500, description = "Internal failure: the message gives the request id (also the x-request-id header); the details are in the server's log under it.", body = ErrorResponse),
        (status = 503, description = "Too many requests are waiting; retry after the Retry-After header's seconds.", body = ErrorResponse,
            headers(("Retry-After" = u64, description = "Seconds to wait before retrying."))),
        (status = 504, description = "The request took longer than the server's timeout.", body = ErrorResponse),
    )
)]
async fn create_trajectory(State(state): State<Shared>, request: Request) -> Result<Json<TrajectoryResponse>, ApiError> {
    within_time_limit(&state, answer_trajectory(&state, request, Instant::now())).await
}

/// The answer of `work`, or 504 when it takes longer than the server's request timeout.
async fn within_time_limit(
    state: &AppState,
    work: impl std::future::Future<Output = Result<TrajectoryResponse, ApiError>>,
) -> Result<Json<TrajectoryResponse>, ApiError> {
    let timeout = state.limits.request_timeout;
    match tokio::time::timeout(timeout, work).await {
        Ok(answer) => answer.map(Json),
        Err(_) => Err(ApiError::new(
            StatusCode::GATEWAY_TIMEOUT,
            "timeout",
            format!("the request took longer than the server's limit of {:.0} s", timeout.as_secs_f64()),
        )),
    }
}

async fn answer_trajectory(state: &AppState, request: Request, started: Instant) -> Result<TrajectoryResponse, ApiError> {
    let input = read_input(request).await?;
    let prompt = input.prompt.as_deref().map(|prompt| check_prompt(prompt, state.limits.max_prompt_chars)).transpose()?;
    let size = check_image(&input.image, state.limits.max_image_side)?;
    let served = state.catalog.select(input.model.as_deref(), input.task.as_deref())?;
    if takes_scans(served) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "needs_scan",
            format!(
                "the model {} predicts from a scan (calibrated depth and label views), not from an image; \
                 POST the scan to /v1/scan-trajectories",
                served.summary.name
            ),
        ));
    }
    let objects = scene_objects(served, prompt.clone(), input.masks, input.objects, size)?;
    let job = PipelineJob { model_dir: served.dir.clone(), roles: served.summary.roles.clone(), image: input.image, objects };
    run_job(state, served, job, prompt, input.include_masks, started).await
}

fn takes_scans(served: &ServedModel) -> bool {
    served.summary.inputs.iter().any(|input| input == "scan")
}

/// Queues `job`, waits for its answer, records the stage timings and builds the response.
async fn run_job(
    state: &AppState,
    served: &ServedModel,
    job: PipelineJob,
    prompt: Option<String>,
    include_masks: bool,
    started: Instant,
) -> Result<TrajectoryResponse, ApiError> {
    let receiver = state.pipeline.submit(job).map_err(|refused| match refused {
        Refused::Full { capacity, retry_after_s } => ApiError::overloaded(retry_after_s, capacity),
        Refused::Stopped => ApiError::new(StatusCode::SERVICE_UNAVAILABLE, "shutting_down", "the server is shutting down"),
    })?;
    let done = receiver.await.map_err(|_| ApiError::internal("the Python worker stopped before answering"))?;
    let output = done.result?;
    let waited = done.waited.as_secs_f64();
    let total = started.elapsed().as_secs_f64();
    for (stage, seconds) in [("queue", waited), ("segment", output.segment_s), ("infer", output.infer_s), ("total", total)] {
        state.metrics.record_stage(stage, seconds);
    }
    let timings = StageTimings {
        queue_ms: waited * 1e3,
        segment_ms: output.segment_s * 1e3,
        infer_ms: output.infer_s * 1e3,
        total_ms: total * 1e3,
        batch_size: done.batch_size as u32,
    };
    build_response(served, prompt, output, timings, include_masks)
}

/// Predict a trajectory from a scan, with a model that takes scans (cnfmp-3d).
///
/// A scan is several calibrated depth views with their label maps: `cameras` (the scan's
/// cameras.json) and every file it names, each as a form file whose field name is that file
/// name, as `cnfmp predict --scan DIR` reads a directory (README, "3D scenes"). Or a
/// labelled point cloud with its sensor origins: one `cloud` file (.npz or .ply).
#[utoipa::path(
    post,
    path = "/v1/scan-trajectories",
    request_body(description = "The scan: cameras.json and the files it names.", content((ScanTrajectoryForm = "multipart/form-data"))),
    responses(
        (status = 200, description = "The trajectory, each object's fit, and stage timings.", body = TrajectoryResponse),
        (status = 400, description = "Malformed form or scan: cameras.json unreadable or without views, a named file missing or not sent, a view without intrinsics or pose, depth of another size than its label map, NaN depth, no points of an object.", body = ErrorResponse),
        (status = 404, description = "Unknown model or task.", body = ErrorResponse),
        (status = 413, description = "The body is too large.", body = ErrorResponse),
        (status = 415, description = "Not multipart/form-data.", body = ErrorResponse),
        (status = 422, description = "The model predicts from images, not scans; or a prompt was sent for a model without prompt roles.", body = ErrorResponse),
        (status = 500, description = "Internal failure: the message gives the request id.", body = ErrorResponse),
        (status = 503, description = "Too many requests are waiting; retry after the Retry-After header's seconds.", body = ErrorResponse,
            headers(("Retry-After" = u64, description = "Seconds to wait before retrying."))),
        (status = 504, description = "The request took longer than the server's timeout.", body = ErrorResponse),
    )
)]
async fn create_scan_trajectory(State(state): State<Shared>, request: Request) -> Result<Json<TrajectoryResponse>, ApiError> {
    within_time_limit(&state, answer_scan_trajectory(&state, request, Instant::now())).await
}

async fn answer_scan_trajectory(state: &AppState, request: Request, started: Instant) -> Result<TrajectoryResponse, ApiError> {
    if content_type(request.headers()) != "multipart/form-data" {
        return Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            "send the scan as multipart/form-data: a `cameras` file (cameras.json) and the files it names",
        ));
    }
    let form = read_scan_form(request).await?;
    let served = state.catalog.select(form.model.as_deref(), form.task.as_deref())?;
    if !takes_scans(served) {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "needs_image",
            format!("the model {} predicts from an image and masks or a prompt; POST them to /v1/trajectories", served.summary.name),
        ));
    }
    let scan = match (form.cameras, form.cloud) {
        (Some(cameras), None) => write_scan_files(cameras, form.files)?,
        (None, Some(cloud)) if form.files.is_empty() => write_point_cloud(cloud)?,
        (None, Some(_)) => {
            return Err(ApiError::bad_request("unknown_field", "a point cloud request takes `cloud` alone (and task, model), no other files"));
        }
        (Some(_), Some(_)) => {
            return Err(ApiError::bad_request("invalid_scan", "send either a scan (`cameras` and its files) or a point cloud (`cloud`), not both"));
        }
        (None, None) => {
            return Err(ApiError::bad_request(
                "missing_field",
                "the form has neither a \"cameras\" field (the scan's cameras.json) nor a \"cloud\" file (.npz or .ply)",
            ));
        }
    };
    let prompt = form.prompt.as_deref().map(|prompt| check_prompt(prompt, state.limits.max_prompt_chars)).transpose()?;
    if prompt.is_some() && served.summary.roles.is_none() {
        return Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "not_promptable",
            format!("the model {} has no prompt roles; send the scan with its label maps", served.summary.name),
        ));
    }
    let scan = UploadedScan { prompt: prompt.clone(), ..scan };
    let job = PipelineJob { model_dir: served.dir.clone(), roles: None, image: Vec::new(), objects: SceneObjects::Scan(Arc::new(scan)) };
    run_job(state, served, job, prompt, false, started).await
}

/// A scan request's form: cameras.json and the files by name, or a point cloud; which model.
struct ScanForm {
    cameras: Option<Vec<u8>>,
    cloud: Option<Vec<u8>>,
    prompt: Option<String>,
    files: Vec<(String, Vec<u8>)>,
    task: Option<String>,
    model: Option<String>,
}

async fn read_scan_form(request: Request) -> Result<ScanForm, ApiError> {
    let mut form = Multipart::from_request(request, &())
        .await
        .map_err(|rejection| ApiError::bad_request("malformed_form", rejection.body_text()))?;
    let (mut cameras, mut cloud, mut files, mut task, mut model, mut prompt) = (None, None, Vec::new(), None, None, None);
    loop {
        let field = match form.next_field().await {
            Ok(Some(field)) => field,
            Ok(None) => break,
            Err(err) => return Err(form_error(err)),
        };
        let name = field.name().unwrap_or_default().to_owned();
        let bytes = field.bytes().await.map_err(form_error)?.to_vec();
        let text = |bytes: Vec<u8>| {
            String::from_utf8(bytes).map_err(|_| ApiError::bad_request("invalid_field", format!("the form field {name:?} is not UTF-8 text")))
        };
        match name.as_str() {
            "cameras" if cameras.is_none() => cameras = Some(bytes),
            "cloud" if cloud.is_none() => cloud = Some(bytes),
            "task" if task.is_none() => task = Some(text(bytes)?),
            "model" if model.is_none() => model = Some(text(bytes)?),
            "prompt" if prompt.is_none() => prompt = Some(text(bytes)?),
            "cameras" | "cloud" | "task" | "model" | "prompt" => {
                return Err(ApiError::bad_request("duplicate_field", format!("the form field {name:?} appears twice")));
            }
            _ if files.iter().any(|(file, _)| file == &name) => {
                return Err(ApiError::bad_request("duplicate_field", format!("the file {name:?} appears twice")));
            }
            _ => files.push((name, bytes)),
        }
    }
    Ok(ScanForm { cameras, cloud, prompt, files, task, model })
}

/// Writes a point cloud (a .npz or a .ply file, told apart by their first bytes) into a new
/// temporary directory; its content is checked when it is read for the prediction.
fn write_point_cloud(cloud: Vec<u8>) -> Result<UploadedScan, ApiError> {
    let name = if cloud.starts_with(b"PK") {
        "cloud.npz"
    } else if cloud.starts_with(b"ply") {
        "cloud.ply"
    } else {
        return Err(ApiError::bad_request("invalid_scan", "the cloud is neither a .npz (zip) nor a .ply file"));
    };
    let dir = scan_directory()?;
    std::fs::write(dir.path().join(name), &cloud).map_err(|err| ApiError::internal(format!("cannot write the point cloud: {err}")))?;
    Ok(UploadedScan { dir, file: Some(name), prompt: None })
}

fn scan_directory() -> Result<tempfile::TempDir, ApiError> {
    tempfile::Builder::new()
        .prefix("cnfmp-scan-")
        .tempdir()
        .map_err(|err| ApiError::internal(format!("cannot create a scan directory: {err}")))
}

/// Writes a scan's files into a new temporary directory, after checking that cameras.json is
/// JSON with views, that every file it names is a plain file name and was sent, and that
/// nothing else was sent. The scan's content (poses, sizes, depth values) is checked when it
/// is read for the prediction.
fn write_scan_files(cameras: Vec<u8>, files: Vec<(String, Vec<u8>)>) -> Result<UploadedScan, ApiError> {
    let bad = |message: String| ApiError::bad_request("invalid_scan", message);
    let meta: serde_json::Value =
        serde_json::from_slice(&cameras).map_err(|err| bad(format!("cameras is not JSON: {err}")))?;
    let views = meta.get("views").and_then(|v| v.as_array()).filter(|v| !v.is_empty());
    let views = views.ok_or_else(|| bad("cameras needs a non-empty \"views\" list".into()))?;
    let mut named = Vec::new();
    for (index, view) in views.iter().enumerate() {
        let label = view.get("name").and_then(|n| n.as_str()).map_or(format!("view {}", index + 1), |n| format!("view {n}"));
        for key in ["depth", "labels", "rgb"] {
            match view.get(key) {
                None if key == "rgb" => {}
                None => return Err(bad(format!("cameras, {label}: \"{key}\" (its file name) is missing"))),
                Some(value) => {
                    let file = value.as_str().ok_or_else(|| bad(format!("cameras, {label}: \"{key}\" is not a file name")))?;
                    let plain = !file.is_empty() && !file.starts_with('.') && !file.contains(['/', '\\']) && file != "cameras.json";
                    if !plain {
                        return Err(bad(format!("cameras, {label}: {file:?} is not a plain file name")));
                    }
                    named.push(file.to_owned());
                }
            }
        }
    }
    for file in &named {
        if !files.iter().any(|(name, _)| name == file) {
            return Err(ApiError::bad_request("missing_file", format!("cameras names the file {file:?} but the form has no field {file:?}")));
        }
    }
    if let Some((extra, _)) = files.iter().find(|(name, _)| !named.contains(name)) {
        return Err(ApiError::bad_request(
            "unknown_field",
            format!("the form field {extra:?} is not a file cameras names; the form takes cameras, its files, prompt, task, model"),
        ));
    }
    let dir = scan_directory()?;
    let write = |name: &str, bytes: &[u8]| {
        std::fs::write(dir.path().join(name), bytes).map_err(|err| ApiError::internal(format!("cannot write the scan's {name}: {err}")))
    };
    write("cameras.json", &cameras)?;
    for (name, bytes) in &files {
        write(name, bytes)?;
    }
    Ok(UploadedScan { dir, file: None, prompt: None })
}

/// How the request finds its objects: its masks when it sent them (checked against the image
/// and the model's slots), else its prompt, when the model's task has prompt roles.
fn scene_objects(
    served: &ServedModel,
    prompt: Option<String>,
    masks: Option<Vec<u8>>,
    objects: Option<Vec<String>>,
    image_size: (u32, u32),
) -> Result<SceneObjects, ApiError> {
    let mask_error = |err: MaskError| ApiError::bad_request(err.code, err.message);
    match (masks, objects, prompt) {
        (Some(masks), Some(objects), _) => {
            let masks = CoarseMasks::from_png(&masks, objects, image_size).map_err(mask_error)?;
            if !served.takes_distractors {
                masks.check_slots(&served.summary.objects).map_err(mask_error)?;
            }
            Ok(SceneObjects::Masks(masks))
        }
        (Some(_), None, _) => Err(ApiError::bad_request(
            "missing_field",
            "masks need objects: the names of the labelled objects in label order, as a JSON list",
        )),
        (None, Some(_), _) => Err(ApiError::bad_request("missing_field", "objects were sent without masks; send both, or a prompt alone")),
        (None, None, None) => Err(ApiError::bad_request(
            "missing_field",
            "the request has neither a prompt nor masks; send a prompt, or masks and objects",
        )),
        (None, None, Some(prompt)) if served.summary.roles.is_none() => Err(ApiError::new(
            StatusCode::UNPROCESSABLE_ENTITY,
            "not_promptable",
            format!(
                "the prompt {prompt:?} cannot be grounded for the model {}: its objects ({}) have no prompt roles in the \
                 segmenter's vocabulary (prompts/vocabulary.json, task {}). Send the coarse masks with the image \
                 (form fields `masks` and `objects`, or JSON `masks_base64` and `objects`), or add the task's roles to \
                 the vocabulary and serve with a backend whose local weights can find these objects (--backend clipseg \
                 or owlv2-sam)",
                served.summary.name,
                served.summary.objects.join(", "),
                served.summary.task
            ),
        )),
        (None, None, Some(prompt)) => Ok(SceneObjects::Prompt(prompt)),
    }
}

/// `value` rounded to 6 decimals (µm, µs): the model's precision, and a compact answer.
fn micro(value: f64) -> f64 {
    (value * 1e6).round() / 1e6
}

/// A finite number, or None (JSON has no NaN).
fn finite(value: Option<f64>) -> Option<f64> {
    value.filter(|v| v.is_finite())
}

fn build_response(
    served: &ServedModel,
    prompt: Option<String>,
    output: PipelineOutput,
    timings_ms: StageTimings,
    include_masks: bool,
) -> Result<TrajectoryResponse, ApiError> {
    let PipelineOutput { found, prediction, .. } = output;
    // The Rust trajectory checks (unit quaternions, increasing time, ...) guard the wire.
    let trajectory = Predicted::from_json_str(&prediction.json)
        .map_err(|err| ApiError::internal(format!("the model produced an invalid trajectory: {err}")))?;
    let fps = trajectory.fps();
    let (joint_names, frames) = match trajectory {
        Predicted::Pose(trajectory) => {
            let frames = trajectory.frames.iter().map(|frame| {
                let (p, q) = (frame.pose.position, frame.pose.orientation);
                Frame {
                    t: micro(frame.t),
                    position: [p.x, p.y, p.z].map(micro),
                    orientation: [q.w, q.i, q.j, q.k].map(micro),
                    gripper: micro(frame.gripper),
                }
            });
            (None, Frames::Pose(frames.collect()))
        }
        Predicted::Joints(trajectory) => {
            let frames = trajectory.frames.iter().map(|frame| JointFrame {
                t: micro(frame.t),
                joints: frame.joints.iter().copied().map(micro).collect(),
                gripper: micro(frame.gripper),
            });
            (Some(trajectory.joint_names), Frames::Joints(frames.collect()))
        }
    };
    let objects = detected_objects(served, &found, &prediction);
    let segmenter = match &found {
        FoundObjects::Segmented(found) => Some(found.document.backend.clone()),
        FoundObjects::Given(_) | FoundObjects::Scanned => None,
    };
    let masks_png = match &found {
        FoundObjects::Segmented(found) => Some(found.labels_png.clone()),
        FoundObjects::Given(masks) => Some(masks.png()),
        FoundObjects::Scanned => None,
    };
    let masks_png_base64 = masks_png.filter(|_| include_masks).map(|png| base64::engine::general_purpose::STANDARD.encode(png));
    Ok(TrajectoryResponse {
        fps,
        joint_names,
        frames,
        model: ModelRef {
            name: served.summary.name.clone(),
            task: served.summary.task.clone(),
            model_type: served.summary.model_type.clone(),
        },
        prompt,
        segmenter,
        objects,
        scene_psnr_db: finite(prediction.scene_psnr_db),
        timings_ms,
        masks_png_base64,
        recorded: prediction.recorded.map(|r| RecordedFrames { source: r.source, names: r.names, values: r.values }),
    })
}

/// Each object of the answer: what was found (by the segmenter, or in the given masks), the
/// slot it filled and what inference made of it.
fn detected_objects(served: &ServedModel, found: &FoundObjects, prediction: &Prediction) -> Vec<DetectedObject> {
    let estimate = |slot: Option<u32>| slot.and_then(|slot| prediction.objects.iter().find(|o| o.slot == slot));
    let inferred = |slot: Option<u32>| {
        let estimate = estimate(slot);
        let confidence = estimate.filter(|e| e.present).map(|e| Confidence {
            reconstruction_mse: finite(e.reconstruction_mse),
            psnr_db: finite(e.psnr_db),
            mask_iou: finite(e.mask_iou),
        });
        (estimate.and_then(|e| e.weights.clone()), confidence)
    };
    match found {
        FoundObjects::Segmented(found) => {
            let slots = found.document.slots.clone().unwrap_or_default();
            found
                .document
                .objects
                .iter()
                .map(|object| {
                    let slot = slots.iter().find(|s| s.label == object.label).map(|s| s.slot);
                    let (latent_weights, confidence) = inferred(slot);
                    DetectedObject {
                        phrase: object.phrase.clone(),
                        role: object.role.clone(),
                        found: object.found,
                        score: object.score,
                        area: object.area,
                        bbox: object.bbox,
                        centroid: object.centroid,
                        slot,
                        latent_weights,
                        confidence,
                    }
                })
                .collect()
        }
        // A scan's objects are its label maps' labels, label k the model's k-th slot.
        FoundObjects::Scanned => prediction
            .objects
            .iter()
            .map(|estimate| DetectedObject {
                phrase: estimate.name.clone(),
                role: "object".into(),
                found: estimate.present,
                score: 1.0,
                area: 0,
                bbox: None,
                centroid: None,
                slot: Some(estimate.slot),
                latent_weights: estimate.weights.clone(),
                confidence: None,
            })
            .collect(),
        // Label k is the model's k-th slot, as for `cnfmp predict --masks`.
        FoundObjects::Given(masks) => masks
            .objects
            .iter()
            .enumerate()
            .map(|(k, name)| {
                let slot = Some(k as u32 + 1);
                let region = masks.region(k as u8 + 1);
                let (latent_weights, confidence) = inferred(slot);
                let role = served.summary.roles.as_ref().and_then(|roles| roles.get(k).cloned());
                DetectedObject {
                    phrase: name.clone(),
                    role: role.unwrap_or_else(|| "object".into()),
                    found: region.is_some(),
                    score: 1.0,
                    area: region.map_or(0, |r| r.area),
                    bbox: region.map(|r| r.bbox),
                    centroid: region.map(|r| r.centroid),
                    slot,
                    latent_weights,
                    confidence,
                }
            })
            .collect(),
    }
}

/// Base64 with or without padding (clients differ).
const BASE64: GeneralPurpose = GeneralPurpose::new(
    &base64::alphabet::STANDARD,
    GeneralPurposeConfig::new().with_decode_padding_mode(DecodePaddingMode::Indifferent),
);

/// Parses the body as multipart/form-data or JSON, by its content type.
async fn read_input(request: Request) -> Result<TrajectoryInput, ApiError> {
    let content_type = content_type(request.headers());
    match content_type.as_str() {
        "multipart/form-data" => read_form(request).await,
        "application/json" => read_json(request).await,
        other => Err(ApiError::new(
            StatusCode::UNSUPPORTED_MEDIA_TYPE,
            "unsupported_media_type",
            format!(
                "send multipart/form-data (an `image` file and a `prompt` field) or application/json \
                 ({{\"image_base64\", \"prompt\"}}), not {}",
                if other.is_empty() { "a body without a Content-Type" } else { other }
            ),
        )),
    }
}

/// The media type of `Content-Type`, lowercase, without parameters ("" when absent).
fn content_type(headers: &HeaderMap) -> String {
    headers
        .get(header::CONTENT_TYPE)
        .and_then(|value| value.to_str().ok())
        .and_then(|value| value.split(';').next())
        .map(|value| value.trim().to_ascii_lowercase())
        .unwrap_or_default()
}

async fn read_json(request: Request) -> Result<TrajectoryInput, ApiError> {
    let body = Bytes::from_request(request, &())
        .await
        .map_err(|rejection| body_error(rejection.status(), rejection.body_text(), "unreadable_body"))?;
    let deserializer = &mut serde_json::Deserializer::from_slice(&body);
    let request: TrajectoryJsonRequest = serde_path_to_error::deserialize(deserializer).map_err(|err| {
        let inner = err.inner();
        let (code, what) = match inner.classify() {
            serde_json::error::Category::Data if inner.to_string().starts_with("missing field") => ("missing_field", "a field is missing"),
            serde_json::error::Category::Data if inner.to_string().starts_with("unknown field") => ("unknown_field", "unknown field"),
            serde_json::error::Category::Data => ("invalid_field", "a field has the wrong type"),
            _ => ("malformed_json", "the body is not valid JSON"),
        };
        let path = err.path().to_string();
        let location = if path == "." { String::new() } else { format!(" at {path}") };
        ApiError::bad_request(code, format!("{what}{location}: {inner}"))
    })?;
    let decode = |name: &str, text: &str| {
        BASE64.decode(text.trim()).map_err(|err| ApiError::bad_request("invalid_base64", format!("{name} is not base64: {err}")))
    };
    let image = decode("image_base64", &request.image_base64)?;
    let masks = request.masks_base64.as_deref().map(|text| decode("masks_base64", text)).transpose()?;
    Ok(TrajectoryInput {
        image,
        prompt: request.prompt,
        masks,
        objects: request
            .objects
            .map(scene_masks::check_names)
            .transpose()
            .map_err(|err| ApiError::bad_request(err.code, err.message))?,
        task: request.task,
        model: request.model,
        include_masks: request.include_masks.unwrap_or(false),
    })
}

const FORM_FIELDS: &str = "image (file) with prompt, or with masks (file) and objects, and optionally task, model, include_masks";

async fn read_form(request: Request) -> Result<TrajectoryInput, ApiError> {
    let mut form = Multipart::from_request(request, &())
        .await
        .map_err(|rejection| ApiError::bad_request("malformed_form", rejection.body_text()))?;
    let (mut image, mut prompt, mut masks, mut objects) = (None, None, None, None);
    let (mut task, mut model, mut include_masks) = (None, None, None);
    loop {
        let field = match form.next_field().await {
            Ok(Some(field)) => field,
            Ok(None) => break,
            Err(err) => return Err(form_error(err)),
        };
        let name = field.name().unwrap_or_default().to_owned();
        let slot: &mut Option<Vec<u8>> = match name.as_str() {
            "image" => &mut image,
            "prompt" => &mut prompt,
            "masks" => &mut masks,
            "objects" => &mut objects,
            "task" => &mut task,
            "model" => &mut model,
            "include_masks" => &mut include_masks,
            _ => {
                return Err(ApiError::bad_request(
                    "unknown_field",
                    format!("unknown form field {name:?}; the form takes {FORM_FIELDS}"),
                ));
            }
        };
        if slot.is_some() {
            return Err(ApiError::bad_request("duplicate_field", format!("the form field {name:?} appears twice")));
        }
        *slot = Some(field.bytes().await.map_err(form_error)?.to_vec());
    }
    let text = |name: &str, value: Option<Vec<u8>>| -> Result<Option<String>, ApiError> {
        value
            .map(|bytes| {
                String::from_utf8(bytes)
                    .map_err(|_| ApiError::bad_request("invalid_field", format!("the form field {name:?} is not UTF-8 text")))
            })
            .transpose()
    };
    let missing = |name: &str| ApiError::bad_request("missing_field", format!("the form has no {name:?} field; it takes {FORM_FIELDS}"));
    let include_masks = match text("include_masks", include_masks)?.as_deref().map(str::trim) {
        None | Some("false" | "0" | "") => false,
        Some("true" | "1") => true,
        Some(other) => {
            return Err(ApiError::bad_request("invalid_field", format!("include_masks must be true or false, not {other:?}")));
        }
    };
    let objects = objects
        .map(|json| scene_masks::parse_objects_text(&json).map_err(|err| ApiError::bad_request(err.code, err.message)))
        .transpose()?;
    Ok(TrajectoryInput {
        image: image.ok_or_else(|| missing("image"))?,
        prompt: text("prompt", prompt)?,
        masks,
        objects,
        task: text("task", task)?,
        model: text("model", model)?,
        include_masks,
    })
}

fn form_error(err: axum::extract::multipart::MultipartError) -> ApiError {
    body_error(err.status(), err.body_text(), "malformed_form")
}

/// A body that could not be read: 413 `body_too_large` when over the limit, else 400 `code`.
fn body_error(status: StatusCode, message: String, code: &'static str) -> ApiError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        ApiError::too_large("body_too_large", message)
    } else {
        ApiError::bad_request(code, message)
    }
}

/// The prompt, trimmed; 400 when empty or longer than `max_chars`.
fn check_prompt(prompt: &str, max_chars: usize) -> Result<String, ApiError> {
    let prompt = prompt.trim();
    if prompt.is_empty() {
        return Err(ApiError::bad_request("empty_prompt", "the prompt is empty; name the objects, e.g. \"put the red cube on the paper\""));
    }
    let chars = prompt.chars().count();
    if chars > max_chars {
        return Err(ApiError::bad_request(
            "prompt_too_long",
            format!("the prompt has {chars} characters; at most {max_chars} are accepted"),
        ));
    }
    Ok(prompt.to_owned())
}

/// Reads the image's size from its header (no decoding) and refuses what is not an image,
/// has no pixels, or is too large, before any Python work is queued. A file that passes but
/// is corrupt further in is caught when Python decodes it (400 `invalid_input`).
fn check_image(image: &[u8], max_side: u32) -> Result<(u32, u32), ApiError> {
    if image.is_empty() {
        return Err(ApiError::bad_request("invalid_image", "the image is empty"));
    }
    let size = imagesize::blob_size(image).map_err(|_| {
        ApiError::bad_request("invalid_image", "the image is not in a format we read (PNG, JPEG, BMP, ...) or its header is corrupt")
    })?;
    if size.width == 0 || size.height == 0 {
        return Err(ApiError::bad_request("invalid_image", format!("the image is {}x{}; it has no pixels", size.width, size.height)));
    }
    if size.width.max(size.height) > max_side as usize {
        return Err(ApiError::too_large(
            "image_too_large",
            format!("the image is {}x{}; each side must be at most {max_side} px", size.width, size.height),
        ));
    }
    Ok((size.width as u32, size.height as u32))
}

/// Liveness and load: models served, the segmenter in use, the queue.
#[utoipa::path(get, path = "/v1/health", responses((status = 200, description = "The server is up.", body = Health)))]
async fn health(State(state): State<Shared>) -> Json<Health> {
    let queue = state.pipeline.gauges();
    Json(Health {
        status: "ok".into(),
        ready: true,
        ready_after_s: state.ready_after.as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").into(),
        models: state.catalog.models().count(),
        segmenter: state.pipeline.segmenter().to_owned(),
        queue_depth: queue.depth,
        queue_capacity: queue.capacity,
        uptime_s: state.started.elapsed().as_secs_f64(),
    })
}

/// The served models: name, task, object slots, prompt roles, card summary.
#[utoipa::path(get, path = "/v1/models", responses((status = 200, description = "Every served model.", body = ModelList)))]
async fn list_models(State(state): State<Shared>) -> Json<ModelList> {
    Json(ModelList { models: state.catalog.models().map(|m| m.summary.clone()).collect() })
}

/// Prometheus metrics (text exposition format 0.0.4).
#[utoipa::path(get, path = "/metrics", responses((status = 200, description = "Counters, histograms and gauges.", body = String, content_type = "text/plain")))]
async fn metrics(State(state): State<Shared>) -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "text/plain; version=0.0.4; charset=utf-8")], state.metrics.render(state.pipeline.gauges()))
}

/// This description.
#[utoipa::path(get, path = "/openapi.json", responses((status = 200, description = "The OpenAPI document.", content_type = "application/json", body = Object)))]
async fn openapi_json() -> Json<utoipa::openapi::OpenApi> {
    Json(ApiDoc::openapi())
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "cnfmp",
        description = "Compositional Neural Field Movement Primitives: a scene image and a prompt in, a robot trajectory out."
    ),
    paths(create_trajectory, create_scan_trajectory, health, list_models, metrics, openapi_json),
    components(schemas(
        TrajectoryJsonRequest, TrajectoryForm, ScanTrajectoryForm, TrajectoryResponse, Frames, Frame, JointFrame, ModelRef, DetectedObject, Confidence,
        StageTimings, RecordedFrames, ModelList, ModelSummary, Health, ErrorResponse, ErrorDetail
    ))
)]
pub struct ApiDoc;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn prompts_are_trimmed_and_bounded() {
        assert_eq!(check_prompt("  put the red cube on the paper ", 100).unwrap(), "put the red cube on the paper");
        assert_eq!(check_prompt(" \n\t", 100).unwrap_err().code, "empty_prompt");
        assert_eq!(check_prompt(&"a".repeat(101), 100).unwrap_err().code, "prompt_too_long");
    }

    #[test]
    fn images_are_checked_from_their_header() {
        let mut png = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut png, 3, 2);
            encoder.set_color(png::ColorType::Rgb);
            encoder.write_header().unwrap().write_image_data(&[0; 18]).unwrap();
        }
        assert!(check_image(&png, 8).is_ok());
        assert_eq!(check_image(&png, 2).unwrap_err().status, StatusCode::PAYLOAD_TOO_LARGE);
        assert_eq!(check_image(b"hello", 8).unwrap_err().code, "invalid_image");
        assert_eq!(check_image(b"", 8).unwrap_err().code, "invalid_image");
    }

    #[test]
    fn the_openapi_document_names_every_route_and_error_schema() {
        let doc = serde_json::to_value(ApiDoc::openapi()).unwrap();
        for path in ["/v1/trajectories", "/v1/health", "/v1/models", "/metrics", "/openapi.json"] {
            assert!(doc["paths"].get(path).is_some(), "{path} missing from the OpenAPI document");
        }
        let responses = &doc["paths"]["/v1/trajectories"]["post"]["responses"];
        for status in ["200", "400", "404", "413", "415", "422", "503", "504"] {
            assert!(responses.get(status).is_some(), "status {status} undocumented");
        }
        assert!(doc["components"]["schemas"].get("ErrorResponse").is_some());
    }
}
