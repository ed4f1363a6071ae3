//! `cnfmp serve`: the HTTP API (axum) through which a robot stack asks for trajectories.
//!
//! Every served model and the segmenter are loaded before the server listens. Requests are
//! parsed and checked on the async runtime (`routes`); their Python work (segment, then
//! predict: `pipeline`) goes through one bounded queue to the bridge's single worker thread
//! (`queue`), so a burst is answered 503 at once instead of queueing without bound; requests
//! for one model that wait together run as one batch, their objects fitted together. SIGTERM or Ctrl-C stops
//! accepting connections, lets in-flight requests finish, and exits 0.

pub mod api;
mod catalog;
mod error;
mod metrics;
mod pipeline;
mod queue;
mod routes;

use std::io::Write;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use clap::Args;
use segmenter_bridge::Bridge;

use crate::helpers::HelperArgs;
use crate::segmentation::BackendArgs;
use crate::failure::Failure;
use catalog::Catalog;
use pipeline::{BridgePipeline, SegmenterChoice};
use queue::Batching;
use routes::{AppState, Limits};

/// The line `cnfmp serve` prints on stdout once it listens; the address follows it.
pub const LISTENING: &str = "cnfmp serve: listening on http://";

#[derive(Debug, Args)]
pub struct ServeArgs {
    /// Directory of model directories (each written by `cnfmp train`); every one is served,
    /// by its directory name.
    #[arg(long, default_value = "models")]
    models: PathBuf,
    /// Address to listen on. Port 0 picks a free port; the address is printed on stdout.
    #[arg(long, default_value = "127.0.0.1:8080")]
    addr: SocketAddr,
    /// The model used when a request names neither a model nor a task.
    #[arg(long, default_value = "language_pick_place")]
    default_model: String,
    #[command(flatten)]
    segmenter: BackendArgs,
    #[command(flatten)]
    helpers: HelperArgs,
    /// Requests that may wait for the Python worker while it runs one; the next gets 503.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=4096))]
    queue_capacity: u32,
    /// Most requests for the same model served together as one batch (their objects are
    /// fitted together, keeping every core busy); 1 serves each request alone.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u32).range(1..=256))]
    max_batch: u32,
    /// Longest the server waits (ms) for more requests to join a batch once it could start
    /// one; 0 batches only the requests already waiting.
    #[arg(long, default_value_t = 2.0, value_parser = non_negative_ms)]
    max_batch_wait_ms: f64,
    /// Seconds a trajectory request may take, waiting included, before it gets 504.
    #[arg(long, default_value_t = 30.0, value_parser = positive_seconds)]
    request_timeout_s: f64,
    /// Largest request body (bytes).
    #[arg(long, default_value_t = 16 * 1024 * 1024)]
    max_body_bytes: usize,
    /// Largest image side (px); the segmenter reads at most 4096.
    #[arg(long, default_value_t = 4096, value_parser = clap::value_parser!(u32).range(8..=4096))]
    max_image_side: u32,
    /// Longest prompt (characters); the segmenter reads at most 1000.
    #[arg(long, default_value_t = 1000, value_parser = clap::value_parser!(u32).range(1..=1000))]
    max_prompt_chars: u32,
}

fn non_negative_ms(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(ms) if ms.is_finite() && (0.0..=10_000.0).contains(&ms) => Ok(ms),
        _ => Err(format!("{text:?} is not a number of milliseconds in 0..=10000")),
    }
}

fn positive_seconds(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(seconds) if seconds.is_finite() && seconds > 0.0 => Ok(seconds),
        _ => Err(format!("{text:?} is not a positive number of seconds")),
    }
}

pub fn run(args: ServeArgs) -> Result<(), Failure> {
    if !args.models.is_dir() {
        return Err(Failure::BadInput(format!("the models directory {} does not exist", args.models.display())));
    }
    let started = Instant::now();
    let bridge = Bridge::start_default()?;
    args.helpers.start(bridge, "cnfmp serve")?;
    let catalog = Catalog::load(bridge, &args.models, &args.default_model)?;
    let backend = bridge
        .segmenter_preload(&args.segmenter.backend, args.segmenter.weights.clone())
        .map_err(|err| Failure::from(err).with_context("cannot load the segmenter"))?;
    eprintln!("cnfmp serve: segmenter {backend}; ready in {:.1} s", started.elapsed().as_secs_f64());
    let segmenter = SegmenterChoice { backend, weights: args.segmenter.weights.clone() };
    let batching = Batching {
        max_size: args.max_batch as usize,
        max_wait: Duration::from_secs_f64(args.max_batch_wait_ms / 1e3),
    };
    let pipeline = BridgePipeline::start(bridge, args.queue_capacity as usize, batching, segmenter)
        .map_err(|err| Failure::Environment(format!("cannot start the dispatcher thread: {err}")))?;
    let state = Arc::new(AppState {
        catalog,
        pipeline: Box::new(pipeline),
        metrics: metrics::Metrics::default(),
        limits: Limits {
            max_body_bytes: args.max_body_bytes,
            max_image_side: args.max_image_side,
            max_prompt_chars: args.max_prompt_chars as usize,
            request_timeout: Duration::from_secs_f64(args.request_timeout_s),
        },
        started,
        ready_after: started.elapsed(),
    });
    // Two async workers suffice: handlers only parse, check and wait; Python does the work.
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .map_err(|err| Failure::Environment(format!("cannot start the async runtime: {err}")))?;
    runtime.block_on(serve(args.addr, state))
}

async fn serve(addr: SocketAddr, state: Arc<AppState>) -> Result<(), Failure> {
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|err| Failure::BadInput(format!("cannot listen on {addr}: {err}")))?;
    let bound = listener
        .local_addr()
        .map_err(|err| Failure::Environment(format!("cannot read the bound address: {err}")))?;
    {
        let mut stdout = std::io::stdout().lock();
        let _ = writeln!(stdout, "{LISTENING}{bound}");
        let _ = stdout.flush();
    }
    let drain_limit = state.limits.request_timeout.max(Duration::from_secs(60));
    axum::serve(listener, routes::router(Arc::clone(&state)))
        .with_graceful_shutdown(shutdown_signal())
        .await
        .map_err(|err| Failure::Environment(format!("the server failed: {err}")))?;
    // Requests in flight were answered; work abandoned by clients may still run in Python.
    if !tokio::task::block_in_place(|| state.pipeline.wait_idle(drain_limit)) {
        return Err(Failure::Environment(format!(
            "the Python worker did not finish its last job within {} s of the shutdown; exiting anyway",
            drain_limit.as_secs()
        )));
    }
    eprintln!("cnfmp serve: stopped");
    Ok(())
}

/// Resolves on SIGTERM or Ctrl-C (SIGINT).
async fn shutdown_signal() {
    let terminate = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut signal) => {
                signal.recv().await;
            }
            Err(err) => {
                eprintln!("cnfmp serve: cannot watch SIGTERM ({err}); stop with Ctrl-C");
                std::future::pending::<()>().await;
            }
        }
    };
    tokio::select! {
        _ = tokio::signal::ctrl_c() => {},
        () = terminate => {},
    }
    eprintln!("cnfmp serve: shutting down; finishing requests in flight");
}

#[cfg(test)]
mod tests;
