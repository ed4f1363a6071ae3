//! The bounded queue in front of the Python worker. The bridge runs Python on one thread, so
//! requests are served one at a time; rather than letting them pile up without bound, at
//! most `capacity` may wait and the next one is refused at once (the server answers 503 with
//! `Retry-After`). A request whose client gave up (timeout, disconnect) before its turn is
//! dropped unrun, so abandoned work never delays the living.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use segmenter_bridge::Bridge;
use tokio::sync::{mpsc, oneshot};

type Work<T> = Box<dyn FnOnce(&Bridge) -> T + Send>;

struct Job<T> {
    work: Work<T>,
    reply: oneshot::Sender<Done<T>>,
    queued_at: Instant,
}

/// A finished job: its result and how long it waited for its turn.
pub struct Done<T> {
    pub waited: Duration,
    pub result: T,
}

/// Why the queue refused a job.
#[derive(Debug, Clone, Copy)]
pub enum Refused {
    /// `capacity` jobs already wait. `retry_after_s` is a fair guess of when a slot frees up
    /// (s, at least 1): the jobs ahead times the mean job's duration.
    Full { capacity: usize, retry_after_s: u64 },
    /// The dispatcher thread is gone (the process is shutting down).
    Stopped,
}

/// Handle to the queue and its dispatcher thread (which ends when every handle is dropped).
#[derive(Clone)]
pub struct PythonQueue<T> {
    jobs: mpsc::Sender<Job<T>>,
    capacity: usize,
    stats: Arc<Stats>,
}

#[derive(Default)]
struct Stats {
    /// Jobs queued or running.
    pending: AtomicUsize,
    finished: AtomicU64,
    busy_micros: AtomicU64,
}

impl<T: Send + 'static> PythonQueue<T> {
    /// Starts the dispatcher thread, which runs jobs in order against `bridge`.
    pub fn start(bridge: &'static Bridge, capacity: usize) -> std::io::Result<Self> {
        let (jobs, mut inbox) = mpsc::channel::<Job<T>>(capacity);
        let stats = Arc::new(Stats::default());
        let worker_stats = Arc::clone(&stats);
        std::thread::Builder::new().name("cnfmp-dispatch".into()).spawn(move || {
            while let Some(job) = inbox.blocking_recv() {
                let waited = job.queued_at.elapsed();
                if !job.reply.is_closed() {
                    let started = Instant::now();
                    // A panicking job drops its reply (its request gets a 500); the next runs.
                    if let Ok(result) = catch_unwind(AssertUnwindSafe(|| (job.work)(bridge))) {
                        let _ = job.reply.send(Done { waited, result });
                    }
                    let micros = started.elapsed().as_micros() as u64;
                    worker_stats.busy_micros.fetch_add(micros, Ordering::Relaxed);
                    worker_stats.finished.fetch_add(1, Ordering::Relaxed);
                }
                worker_stats.pending.fetch_sub(1, Ordering::Relaxed);
            }
        })?;
        Ok(PythonQueue { jobs, capacity, stats })
    }

    /// Queues `work`, or refuses it at once when `capacity` jobs already wait. Dropping the
    /// receiver before the job's turn cancels it.
    pub fn submit(&self, work: impl FnOnce(&Bridge) -> T + Send + 'static) -> Result<oneshot::Receiver<Done<T>>, Refused> {
        let (reply, receiver) = oneshot::channel();
        let job = Job { work: Box::new(work), reply, queued_at: Instant::now() };
        self.stats.pending.fetch_add(1, Ordering::Relaxed);
        let Err(refused) = self.jobs.try_send(job) else {
            return Ok(receiver);
        };
        self.stats.pending.fetch_sub(1, Ordering::Relaxed);
        Err(match refused {
            mpsc::error::TrySendError::Full(_) => {
                Refused::Full { capacity: self.capacity, retry_after_s: self.retry_after_s() }
            }
            mpsc::error::TrySendError::Closed(_) => Refused::Stopped,
        })
    }

    /// Jobs waiting for their turn (not counting the one running).
    pub fn depth(&self) -> usize {
        self.jobs.max_capacity() - self.jobs.capacity()
    }

    /// Jobs waiting or running.
    pub fn pending(&self) -> usize {
        self.stats.pending.load(Ordering::Relaxed)
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Waits (up to `limit`) until no job runs or waits; returns whether that happened. A
    /// job whose client gave up keeps running until it ends, and exiting the process while
    /// Python runs it would crash the interpreter mid-call.
    pub fn wait_idle(&self, limit: Duration) -> bool {
        let deadline = Instant::now() + limit;
        while self.pending() > 0 {
            if Instant::now() >= deadline {
                return false;
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        true
    }

    fn retry_after_s(&self) -> u64 {
        let finished = self.stats.finished.load(Ordering::Relaxed).max(1);
        let mean_s = self.stats.busy_micros.load(Ordering::Relaxed) as f64 / finished as f64 / 1e6;
        ((self.pending() as f64 * mean_s).ceil() as u64).max(1)
    }
}
