//! The server's one error type: every failure becomes `{"error": {"code", "message"}}` with
//! the right status, so clients can branch on `code` and show `message` to a person. An
//! internal failure (500) tells the client only "internal error" and the request's id; its
//! details ride in the response's extensions to the request middleware, which logs them.

use std::sync::atomic::{AtomicU64, Ordering};

use axum::Json;
use axum::http::{HeaderValue, StatusCode, header};
use axum::response::{IntoResponse, Response};
use segmenter_bridge::BridgeError;

use super::api::{ErrorDetail, ErrorResponse};

/// A failed request.
#[derive(Debug, Clone)]
pub struct ApiError {
    pub status: StatusCode,
    /// Stable machine-readable code (snake_case).
    pub code: &'static str,
    pub message: String,
    /// Seconds for the `Retry-After` header (503 only).
    pub retry_after_s: Option<u64>,
    /// What went wrong inside (500 only): for the log, never for the client.
    pub internal_detail: Option<String>,
}

/// The error code of a response, kept in its extensions for the metrics.
#[derive(Debug, Clone, Copy)]
pub struct ErrorCode(pub &'static str);

/// An internal error's details, kept in the response's extensions for the log.
#[derive(Debug, Clone)]
pub struct InternalDetail(pub String);

tokio::task_local! {
    /// The id of the request being answered (set by the request middleware).
    pub static REQUEST_ID: String;
}

/// The id of a request: the client's `x-request-id` when it is 1-64 characters of
/// `[A-Za-z0-9._-]`, else a new one unique on this host (process id and a counter).
pub fn request_id(given: Option<&axum::http::HeaderValue>) -> String {
    static NEXT: AtomicU64 = AtomicU64::new(1);
    let sane = |id: &str| (1..=64).contains(&id.len()) && id.bytes().all(|b| b.is_ascii_alphanumeric() || b"._-".contains(&b));
    match given.and_then(|value| value.to_str().ok()).filter(|id| sane(id)) {
        Some(id) => id.to_owned(),
        None => format!("{:x}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::Relaxed)),
    }
}

impl ApiError {
    pub fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        ApiError { status, code, message: message.into(), retry_after_s: None, internal_detail: None }
    }

    /// 500: a failure of the environment or of the code, not of the request. `detail` goes
    /// to the server's log only.
    pub fn internal(detail: impl Into<String>) -> Self {
        ApiError { internal_detail: Some(detail.into()), ..ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", "internal error") }
    }

    /// 400: the request is malformed or a field is invalid.
    pub fn bad_request(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::BAD_REQUEST, code, message)
    }

    /// 404: the request names a model or task that is not served.
    pub fn not_found(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::NOT_FOUND, code, message)
    }

    /// 413: the body or the image is larger than the server accepts.
    pub fn too_large(code: &'static str, message: impl Into<String>) -> Self {
        ApiError::new(StatusCode::PAYLOAD_TOO_LARGE, code, message)
    }

    /// 503 with `Retry-After`: the queue to the Python worker is full.
    pub fn overloaded(retry_after_s: u64, capacity: usize) -> Self {
        ApiError {
            retry_after_s: Some(retry_after_s),
            ..ApiError::new(
                StatusCode::SERVICE_UNAVAILABLE,
                "overloaded",
                format!("{capacity} request(s) are already waiting for the model; retry after {retry_after_s} s"),
            )
        }
    }
}

impl From<BridgeError> for ApiError {
    /// The caller's mistakes become 4xx (the Python side's message says what is wrong); a
    /// failure of the environment or the code is a 500 whose details (a Python traceback
    /// included) go to the log.
    fn from(err: BridgeError) -> Self {
        match err {
            BridgeError::InvalidInput(message) => ApiError::bad_request("invalid_input", message),
            BridgeError::NotGrounded(message) => ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "not_grounded", message),
            BridgeError::Python(exception) => ApiError::internal(format!("{exception}\n{}", exception.traceback_text())),
            other => ApiError::internal(other.to_string()),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let message = match &self.internal_detail {
            Some(_) => match REQUEST_ID.try_with(String::clone) {
                Ok(id) => format!("internal error; the server's log has the details under request id {id}"),
                Err(_) => "internal error; the server's log has the details".to_owned(),
            },
            None => self.message,
        };
        let body = ErrorResponse { error: ErrorDetail { code: self.code.to_owned(), message } };
        let mut response = (self.status, Json(body)).into_response();
        if let Some(seconds) = self.retry_after_s {
            response.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        response.extensions_mut().insert(ErrorCode(self.code));
        if let Some(detail) = self.internal_detail {
            response.extensions_mut().insert(InternalDetail(detail));
        }
        response
    }
}
