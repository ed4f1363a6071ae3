//! The HTTP layer in-process, as axum's testing example does it: the router that `cnfmp serve`
//! runs, over a stand-in pipeline, so every answer the server gives before Python work (4xx,
//! 503) and the shape of a 500 are checked without an interpreter. tests/serve_api.rs drives
//! the real server for the paths that need Python.

use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use axum::Router;
use axum::body::Body;
use axum::http::{HeaderValue, Method, Request, StatusCode};
use serde_json::{Value, json};
use tokio::sync::oneshot;
use tower::ServiceExt;

use super::api::ModelSummary;
use super::catalog::{Catalog, ServedModel};
use super::error::ApiError;
use super::metrics::{Metrics, QueueGauges};
use super::pipeline::{Pipeline, PipelineJob, PipelineResult};
use super::queue::{Done, Refused};
use super::routes::{AppState, Limits, router};

/// What the stand-in pipeline answers to every job it is given.
#[derive(Clone, Copy)]
enum Behaviour {
    /// The queue is full.
    Refuse,
    /// The job fails inside (as a Python exception would).
    FailInside,
}

struct FakePipeline {
    behaviour: Behaviour,
    submitted: Arc<AtomicUsize>,
}

impl Pipeline for FakePipeline {
    fn submit(&self, _job: PipelineJob) -> Result<oneshot::Receiver<Done<PipelineResult>>, Refused> {
        self.submitted.fetch_add(1, Ordering::SeqCst);
        match self.behaviour {
            Behaviour::Refuse => Err(Refused::Full { capacity: 2, retry_after_s: 3 }),
            Behaviour::FailInside => {
                let (reply, receiver) = oneshot::channel();
                let failure = ApiError::internal("Traceback: RuntimeError: secret detail of the worker");
                let _ = reply.send(Done { waited: Duration::ZERO, batch_size: 1, result: Err(failure) });
                Ok(receiver)
            }
        }
    }

    fn gauges(&self) -> QueueGauges {
        QueueGauges { depth: 0, capacity: 2, pending: 0 }
    }

    fn segmenter(&self) -> &str {
        "color"
    }

    fn wait_idle(&self, _limit: Duration) -> bool {
        true
    }
}

fn model(name: &str, task: &str, roles: Option<&[&str]>) -> ServedModel {
    let objects = vec!["block".to_owned(), "tray".to_owned()];
    ServedModel {
        dir: format!("/nonexistent/{name}").into(),
        summary: ModelSummary {
            name: name.into(),
            task: task.into(),
            model_type: "cnfmp".into(),
            objects,
            roles: roles.map(|roles| roles.iter().map(|r| (*r).to_owned()).collect()),
            inputs: vec!["masks".into()],
            parameters: 1,
            output_fps: 20.0,
            duration_s: 4.0,
            default: false,
            card: Default::default(),
        },
        takes_distractors: false,
    }
}

/// The app over two models (one promptable, one served from masks only) and a fake pipeline.
fn app(behaviour: Behaviour) -> (Router, Arc<AtomicUsize>) {
    let submitted = Arc::new(AtomicUsize::new(0));
    let catalog = Catalog::new(
        vec![model("pick", "language_pick_place", Some(&["target", "destination"])), model("cups", "cup_stacking", None)],
        "pick",
    );
    let state = AppState {
        catalog,
        pipeline: Box::new(FakePipeline { behaviour, submitted: Arc::clone(&submitted) }),
        metrics: Metrics::default(),
        limits: Limits {
            max_body_bytes: 1_000_000,
            max_image_side: 1024,
            max_prompt_chars: 200,
            request_timeout: Duration::from_secs(5),
        },
        started: Instant::now(),
        ready_after: Duration::from_secs(1),
    };
    (router(Arc::new(state)), submitted)
}

struct Answer {
    status: StatusCode,
    request_id: Option<String>,
    body: Value,
}

async fn send(app: &Router, request: Request<Body>) -> Answer {
    let response = app.clone().oneshot(request).await.expect("the router answers");
    let status = response.status();
    let request_id = response.headers().get("x-request-id").and_then(|v| v.to_str().ok()).map(str::to_owned);
    let bytes = axum::body::to_bytes(response.into_body(), usize::MAX).await.expect("a body");
    Answer { status, request_id, body: serde_json::from_slice(&bytes).unwrap_or(Value::Null) }
}

fn post(content_type: &str, body: Vec<u8>) -> Request<Body> {
    Request::post("/v1/trajectories").header("content-type", content_type).body(Body::from(body)).unwrap()
}

fn png(width: u32, height: u32) -> Vec<u8> {
    let mut out = Vec::new();
    let mut encoder = png::Encoder::new(&mut out, width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.write_header().unwrap().write_image_data(&vec![0u8; (width * height) as usize]).unwrap();
    out
}

/// A well-formed PNG whose header claims 0x0 pixels (no encoder writes one).
fn zero_by_zero_png() -> Vec<u8> {
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &byte in bytes {
            crc ^= u32::from(byte);
            for _ in 0..8 {
                crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        !crc
    }
    fn chunk(out: &mut Vec<u8>, kind: &[u8], data: &[u8]) {
        out.extend_from_slice(&(data.len() as u32).to_be_bytes());
        let start = out.len();
        out.extend_from_slice(kind);
        out.extend_from_slice(data);
        let crc = crc32(&out[start..]);
        out.extend_from_slice(&crc.to_be_bytes());
    }
    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    chunk(&mut out, b"IHDR", &[0, 0, 0, 0, 0, 0, 0, 0, 8, 2, 0, 0, 0]);
    chunk(&mut out, b"IEND", &[]);
    out
}

/// A multipart form: `image` as a file (when given) and text fields.
fn form(image: Option<&[u8]>, fields: &[(&str, &str)]) -> (String, Vec<u8>) {
    let mut body = Vec::new();
    if let Some(image) = image {
        body.extend(b"--b0undary\r\nContent-Disposition: form-data; name=\"image\"; filename=\"scene.png\"\r\nContent-Type: image/png\r\n\r\n");
        body.extend(image);
        body.extend(b"\r\n");
    }
    for (name, value) in fields {
        body.extend(format!("--b0undary\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n{value}\r\n").as_bytes());
    }
    body.extend(b"--b0undary--\r\n");
    ("multipart/form-data; boundary=b0undary".into(), body)
}

fn json_body(value: Value) -> (String, Vec<u8>) {
    ("application/json".into(), value.to_string().into_bytes())
}

/// A bad request: what it is, its content type and body, the status and code it must get.
type BadRequest = (&'static str, (String, Vec<u8>), u16, &'static str);

#[tokio::test]
async fn bad_requests_get_their_4xx_before_any_work_is_queued() {
    let (app, submitted) = app(Behaviour::FailInside);
    let image = png(32, 24);
    let prompt = "put the red block on the tray";
    let long_prompt = "put the block on the tray ".repeat(20);
    let cases: Vec<BadRequest> = vec![
        ("not an image", form(Some(b"this is not an image"), &[("prompt", prompt)]), 400, "invalid_image"),
        ("empty image", form(Some(b""), &[("prompt", prompt)]), 400, "invalid_image"),
        ("0x0 image", form(Some(&zero_by_zero_png()), &[("prompt", prompt)]), 400, "invalid_image"),
        ("image over the side limit", form(Some(&png(2000, 10)), &[("prompt", prompt)]), 413, "image_too_large"),
        ("empty prompt", form(Some(&image), &[("prompt", "  ")]), 400, "empty_prompt"),
        ("long prompt", form(Some(&image), &[("prompt", &long_prompt)]), 400, "prompt_too_long"),
        ("unknown model", form(Some(&image), &[("prompt", prompt), ("model", "nope")]), 404, "unknown_model"),
        ("unknown task", form(Some(&image), &[("prompt", prompt), ("task", "juggling")]), 404, "unknown_task"),
        ("model and task disagree", form(Some(&image), &[("prompt", prompt), ("model", "pick"), ("task", "cup_stacking")]), 400, "model_task_mismatch"),
        ("prompt for a masks-only model", form(Some(&image), &[("prompt", prompt), ("task", "cup_stacking")]), 422, "not_promptable"),
        ("unknown form field", form(Some(&image), &[("prompt", prompt), ("promt", "x")]), 400, "unknown_field"),
        ("duplicate form field", form(Some(&image), &[("prompt", prompt), ("prompt", prompt)]), 400, "duplicate_field"),
        ("form without image", form(None, &[("prompt", prompt)]), 400, "missing_field"),
        ("neither prompt nor masks", form(Some(&image), &[]), 400, "missing_field"),
        ("masks without objects", form(Some(&image), &[("masks", "x")]), 400, "missing_field"),
        ("objects without masks", form(Some(&image), &[("objects", "[\"block\"]")]), 400, "missing_field"),
        ("bad include_masks", form(Some(&image), &[("prompt", prompt), ("include_masks", "maybe")]), 400, "invalid_field"),
        ("broken form", ("multipart/form-data; boundary=abc".into(), b"--abc\r\nContent-Disposition: form-data\r\n".to_vec()), 400, "malformed_form"),
        ("wrong content type", ("text/plain".into(), prompt.as_bytes().to_vec()), 415, "unsupported_media_type"),
        ("malformed JSON", ("application/json".into(), b"{\"prompt\": ".to_vec()), 400, "malformed_json"),
        ("JSON missing a field", json_body(json!({"prompt": prompt})), 400, "missing_field"),
        ("JSON wrong type", json_body(json!({"image_base64": 3, "prompt": prompt})), 400, "invalid_field"),
        ("JSON unknown field", json_body(json!({"image_base64": "", "prompt": prompt, "colour": 1})), 400, "unknown_field"),
        ("JSON bad base64", json_body(json!({"image_base64": "%%%", "prompt": prompt})), 400, "invalid_base64"),
        ("body over the limit", form(Some(&vec![0u8; 1_200_000]), &[("prompt", prompt)]), 413, "body_too_large"),
    ];
    for (name, (content_type, body), status, code) in cases {
        let answer = send(&app, post(&content_type, body)).await;
        assert_eq!(answer.status.as_u16(), status, "{name}: {}", answer.body);
        assert_eq!(answer.body["error"]["code"], code, "{name}: {}", answer.body);
        assert!(answer.body["error"]["message"].as_str().is_some_and(|m| m.len() > 10), "{name}: {}", answer.body);
        assert!(answer.request_id.is_some(), "{name}: no x-request-id");
    }
    assert_eq!(submitted.load(Ordering::SeqCst), 0, "a bad request reached the pipeline");

    let unknown = send(&app, Request::get("/v1/nothing-here").body(Body::empty()).unwrap()).await;
    assert_eq!((unknown.status, unknown.body["error"]["code"].as_str()), (StatusCode::NOT_FOUND, Some("unknown_route")));
    let delete = send(&app, Request::builder().method(Method::DELETE).uri("/v1/models").body(Body::empty()).unwrap()).await;
    assert_eq!((delete.status, delete.body["error"]["code"].as_str()), (StatusCode::METHOD_NOT_ALLOWED, Some("method_not_allowed")));
}

#[tokio::test]
async fn a_full_queue_gets_503_with_retry_after() {
    let (app, submitted) = app(Behaviour::Refuse);
    let (content_type, body) = form(Some(&png(32, 24)), &[("prompt", "put the red block on the tray")]);
    let response = app.clone().oneshot(post(&content_type, body)).await.unwrap();
    assert_eq!(response.status(), StatusCode::SERVICE_UNAVAILABLE);
    assert_eq!(response.headers().get("retry-after").and_then(|v| v.to_str().ok()), Some("3"));
    assert_eq!(submitted.load(Ordering::SeqCst), 1);
}

#[tokio::test]
async fn an_internal_error_tells_the_client_only_its_request_id() {
    let (app, _) = app(Behaviour::FailInside);
    let with_id = |id: &str| {
        let (content_type, body) = form(Some(&png(32, 24)), &[("prompt", "put the red block on the tray")]);
        let mut request = post(&content_type, body);
        request.headers_mut().insert("x-request-id", HeaderValue::from_str(id).unwrap());
        request
    };
    let answer = send(&app, with_id("robot-7.42")).await;
    assert_eq!(answer.status, StatusCode::INTERNAL_SERVER_ERROR);
    assert_eq!(answer.body["error"]["code"], "internal");
    let message = answer.body["error"]["message"].as_str().unwrap();
    assert!(message.contains("robot-7.42"), "{message}");
    assert!(!message.contains("secret") && !message.contains("Traceback"), "the details leaked: {message}");
    assert_eq!(answer.request_id.as_deref(), Some("robot-7.42"));

    // A request id that is not a sane token is replaced by the server's own.
    let answer = send(&app, with_id("a b\tc")).await;
    let id = answer.request_id.expect("an id");
    assert_ne!(id, "a b\tc");
    assert!(answer.body["error"]["message"].as_str().unwrap().contains(&id));
}

#[tokio::test]
async fn health_and_models_answer_from_the_catalog() {
    let (app, _) = app(Behaviour::Refuse);
    let health = send(&app, Request::get("/v1/health").body(Body::empty()).unwrap()).await;
    assert_eq!(health.status, StatusCode::OK);
    assert_eq!((health.body["models"].as_u64(), health.body["segmenter"].as_str()), (Some(2), Some("color")));
    let models = send(&app, Request::get("/v1/models").body(Body::empty()).unwrap()).await;
    let defaults: Vec<&str> = models.body["models"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|m| m["default"] == true)
        .map(|m| m["name"].as_str().unwrap())
        .collect();
    assert_eq!(defaults, ["pick"]);
}
