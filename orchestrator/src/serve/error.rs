//! The server's one error type: every failure becomes `{"error": {"code", "message"}}` with
//! the right status, so clients can branch on `code` and show `message` to a person.

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
}

/// The error code of a response, kept in its extensions for the metrics.
#[derive(Debug, Clone, Copy)]
pub struct ErrorCode(pub &'static str);

impl ApiError {
    pub fn new(status: StatusCode, code: &'static str, message: impl Into<String>) -> Self {
        ApiError { status, code, message: message.into(), retry_after_s: None }
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
    /// failure of the environment or the code is a 500, logged in full on stderr.
    fn from(err: BridgeError) -> Self {
        match err {
            BridgeError::InvalidInput(message) => ApiError::bad_request("invalid_input", message),
            BridgeError::NotGrounded(message) => {
                ApiError::new(StatusCode::UNPROCESSABLE_ENTITY, "not_grounded", message)
            }
            other => {
                if let BridgeError::Python(exception) = &other {
                    eprintln!("cnfmp serve: internal error: {exception}\n{}", exception.traceback_text());
                } else {
                    eprintln!("cnfmp serve: internal error: {other}");
                }
                ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, "internal", other.to_string())
            }
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorResponse { error: ErrorDetail { code: self.code.to_owned(), message: self.message } };
        let mut response = (self.status, Json(body)).into_response();
        if let Some(seconds) = self.retry_after_s {
            response.headers_mut().insert(header::RETRY_AFTER, HeaderValue::from(seconds));
        }
        response.extensions_mut().insert(ErrorCode(self.code));
        response
    }
}
