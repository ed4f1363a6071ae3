//! The bounded queue in front of the Python worker, with dynamic batching. The bridge runs
//! Python on one thread, so rather than letting requests pile up without bound, at most
//! `capacity` may wait and the next one is refused at once (the server answers 503 with
//! `Retry-After`). When the worker frees up, the dispatcher takes the oldest waiting job and
//! up to `max_size - 1` more that wait for the same model (the batch key), lingering at most
//! `max_wait` for them, and runs them as one batch: Python fits every object of the batch
//! together, which keeps both cores busy where one scene's few objects would not. A job whose
//! client gave up (timeout, disconnect) before its turn is dropped unrun, so abandoned work
//! never delays the living.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError, SyncSender, TryRecvError, TrySendError};
use std::time::{Duration, Instant};

use tokio::sync::oneshot;

struct Job<J, T> {
    input: J,
    reply: oneshot::Sender<Done<T>>,
    queued_at: Instant,
}

/// A finished job: its result, how long it waited for its turn, and how many jobs its batch
/// held (itself included).
pub struct Done<T> {
    pub waited: Duration,
    pub batch_size: usize,
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

/// How the dispatcher forms batches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Batching {
    /// Most jobs in one batch (1: every job runs alone).
    pub max_size: usize,
    /// Longest the dispatcher waits for more jobs once it holds the first one.
    pub max_wait: Duration,
}

/// Handle to the queue and its dispatcher thread (which ends when every handle is dropped).
pub struct PythonQueue<J, T> {
    jobs: SyncSender<Job<J, T>>,
    capacity: usize,
    stats: Arc<Stats>,
}

#[derive(Default)]
struct Stats {
    /// Jobs queued or running.
    pending: AtomicUsize,
    /// Jobs queued, not yet taken by the dispatcher.
    waiting: AtomicUsize,
    finished: AtomicU64,
    busy_micros: AtomicU64,
}

impl<J: Send + 'static, T: Send + 'static> PythonQueue<J, T> {
    /// Starts the dispatcher thread. It forms batches of jobs with equal `key` (see
    /// [`Batching`]) and runs each with `run` (the Python work), which must return one result
    /// per input, in order.
    pub fn start<K, KeyFn, RunFn>(capacity: usize, batching: Batching, key: KeyFn, run: RunFn) -> std::io::Result<Self>
    where
        K: PartialEq,
        KeyFn: Fn(&J) -> K + Send + 'static,
        RunFn: Fn(Vec<J>) -> Vec<T> + Send + 'static,
    {
        let (jobs, inbox) = mpsc::sync_channel::<Job<J, T>>(capacity);
        let stats = Arc::new(Stats::default());
        let worker_stats = Arc::clone(&stats);
        std::thread::Builder::new().name("cnfmp-dispatch".into()).spawn(move || {
            let mut dispatcher = Dispatcher { inbox, held: None, batching, stats: worker_stats };
            while let Some(batch) = dispatcher.next_batch(&key) {
                dispatcher.run(batch, &run);
            }
        })?;
        Ok(PythonQueue { jobs, capacity, stats })
    }

    /// Queues `input`, or refuses it at once when `capacity` jobs already wait. Dropping the
    /// receiver before the job's turn cancels it.
    pub fn submit(&self, input: J) -> Result<oneshot::Receiver<Done<T>>, Refused> {
        let (reply, receiver) = oneshot::channel();
        let job = Job { input, reply, queued_at: Instant::now() };
        self.stats.pending.fetch_add(1, Ordering::Relaxed);
        self.stats.waiting.fetch_add(1, Ordering::Relaxed);
        let Err(refused) = self.jobs.try_send(job) else {
            return Ok(receiver);
        };
        self.stats.pending.fetch_sub(1, Ordering::Relaxed);
        self.stats.waiting.fetch_sub(1, Ordering::Relaxed);
        Err(match refused {
            TrySendError::Full(_) => Refused::Full { capacity: self.capacity, retry_after_s: self.retry_after_s() },
            TrySendError::Disconnected(_) => Refused::Stopped,
        })
    }

    /// Jobs waiting for their turn (not counting those running).
    pub fn depth(&self) -> usize {
        self.stats.waiting.load(Ordering::Relaxed)
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

/// The dispatcher thread's state: the inbox and a job taken from it that belongs to the next
/// batch (it came for another model while a batch was being formed).
struct Dispatcher<J, T> {
    inbox: mpsc::Receiver<Job<J, T>>,
    held: Option<Job<J, T>>,
    batching: Batching,
    stats: Arc<Stats>,
}

impl<J, T> Dispatcher<J, T> {
    /// The next batch of live jobs (oldest first, all with the first one's key), or None
    /// once every sender is gone. Blocks for the first job, then lingers up to `max_wait`.
    fn next_batch<K: PartialEq>(&mut self, key: &impl Fn(&J) -> K) -> Option<Vec<Job<J, T>>> {
        let mut batch = Vec::new();
        while batch.is_empty() {
            let first = match self.held.take() {
                Some(job) => job,
                None => self.take(self.inbox.recv().ok())?,
            };
            self.keep_if_live(first, &mut batch);
        }
        let batch_key = key(&batch[0].input);
        let deadline = Instant::now() + self.batching.max_wait;
        while batch.len() < self.batching.max_size {
            let next = match self.inbox.try_recv() {
                Ok(job) => job,
                Err(TryRecvError::Disconnected) => break,
                Err(TryRecvError::Empty) => {
                    let left = deadline.saturating_duration_since(Instant::now());
                    match self.inbox.recv_timeout(left) {
                        Ok(job) => job,
                        Err(RecvTimeoutError::Timeout | RecvTimeoutError::Disconnected) => break,
                    }
                }
            };
            let Some(next) = self.take(Some(next)) else { break };
            if key(&next.input) != batch_key {
                self.held = Some(next);
                break;
            }
            self.keep_if_live(next, &mut batch);
        }
        Some(batch)
    }

    /// Counts a job taken off the inbox.
    fn take(&self, job: Option<Job<J, T>>) -> Option<Job<J, T>> {
        if job.is_some() {
            self.stats.waiting.fetch_sub(1, Ordering::Relaxed);
        }
        job
    }

    /// Adds `job` to `batch` unless its client has gone (then it is dropped unrun).
    fn keep_if_live(&self, job: Job<J, T>, batch: &mut Vec<Job<J, T>>) {
        if job.reply.is_closed() {
            self.stats.pending.fetch_sub(1, Ordering::Relaxed);
        } else {
            batch.push(job);
        }
    }

    fn run(&self, batch: Vec<Job<J, T>>, run: &impl Fn(Vec<J>) -> Vec<T>) {
        let size = batch.len();
        let started = Instant::now();
        let (inputs, replies): (Vec<J>, Vec<_>) =
            batch.into_iter().map(|job| (job.input, (job.reply, started.duration_since(job.queued_at)))).unzip();
        // A panicking batch drops its replies (its requests get a 500); the next runs.
        if let Ok(results) = catch_unwind(AssertUnwindSafe(|| run(inputs))) {
            for ((reply, waited), result) in replies.into_iter().zip(results) {
                let _ = reply.send(Done { waited, batch_size: size, result });
            }
        }
        let micros = started.elapsed().as_micros() as u64;
        self.stats.busy_micros.fetch_add(micros, Ordering::Relaxed);
        self.stats.finished.fetch_add(size as u64, Ordering::Relaxed);
        self.stats.pending.fetch_sub(size, Ordering::Relaxed);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    type TestQueue = PythonQueue<(u8, u32), Vec<u32>>;

    /// A queue whose jobs are (key, value) and whose batches report the values they held; a
    /// batch holding a job of value 0 says so on the returned receiver, then blocks until
    /// `release` is sent, so jobs pile up behind it.
    fn queue(batching: Batching) -> (TestQueue, mpsc::Receiver<()>, mpsc::Sender<()>) {
        let (release, gate) = mpsc::channel::<()>();
        let (running_tx, running) = mpsc::channel::<()>();
        let gate = std::sync::Mutex::new((gate, running_tx));
        let queue = PythonQueue::start(8, batching, |job: &(u8, u32)| job.0, move |jobs: Vec<(u8, u32)>| {
            if jobs.iter().any(|job| job.1 == 0) {
                let gate = gate.lock().unwrap();
                gate.1.send(()).unwrap();
                gate.0.recv().unwrap();
            }
            let values: Vec<u32> = jobs.iter().map(|job| job.1).collect();
            vec![values; jobs.len()]
        })
        .unwrap();
        (queue, running, release)
    }

    fn wait_until_running(running: &mpsc::Receiver<()>) {
        running.recv_timeout(Duration::from_secs(10)).expect("the first batch never ran");
    }

    #[test]
    fn waiting_jobs_for_one_model_run_as_one_batch_and_another_model_waits_its_turn() {
        let batching = Batching { max_size: 3, max_wait: Duration::from_millis(1) };
        let (queue, running, release) = queue(batching);
        let blocker = queue.submit((1, 0)).unwrap();
        wait_until_running(&running);
        let waiting: Vec<_> = [(1, 1), (1, 2), (2, 3), (1, 4), (1, 5), (1, 6)]
            .into_iter()
            .map(|job| queue.submit(job).unwrap())
            .collect();
        assert_eq!(queue.depth(), 6);
        release.send(()).unwrap();
        assert_eq!(blocker.blocking_recv().unwrap().result, vec![0]);
        let batches: Vec<(Vec<u32>, usize)> = waiting
            .into_iter()
            .map(|receiver| {
                let done = receiver.blocking_recv().unwrap();
                (done.result, done.batch_size)
            })
            .collect();
        // Model 1's first two, cut short by model 2's job, which then runs alone; then model
        // 1's remaining three fill a batch of the largest size.
        assert_eq!(batches, vec![
            (vec![1, 2], 2),
            (vec![1, 2], 2),
            (vec![3], 1),
            (vec![4, 5, 6], 3),
            (vec![4, 5, 6], 3),
            (vec![4, 5, 6], 3),
        ]);
        assert!(queue.wait_idle(Duration::from_secs(5)));
        assert_eq!(queue.pending(), 0);
    }

    #[test]
    fn a_job_whose_client_left_is_dropped_from_its_batch_unrun() {
        let (queue, running, release) = queue(Batching { max_size: 8, max_wait: Duration::ZERO });
        let blocker = queue.submit((1, 0)).unwrap();
        wait_until_running(&running);
        let kept = queue.submit((1, 1)).unwrap();
        drop(queue.submit((1, 2)).unwrap());
        let also_kept = queue.submit((1, 3)).unwrap();
        release.send(()).unwrap();
        blocker.blocking_recv().unwrap();
        assert_eq!(kept.blocking_recv().unwrap().result, vec![1, 3]);
        assert_eq!(also_kept.blocking_recv().unwrap().batch_size, 2);
        assert!(queue.wait_idle(Duration::from_secs(5)));
    }

    #[test]
    fn a_batch_of_one_waits_no_longer_than_its_wait() {
        let (queue, _running, _release) = queue(Batching { max_size: 8, max_wait: Duration::from_millis(20) });
        let started = Instant::now();
        let done = queue.submit((1, 7)).unwrap().blocking_recv().unwrap();
        assert_eq!((done.result, done.batch_size), (vec![7], 1));
        let took = started.elapsed();
        assert!(took >= Duration::from_millis(20) && took < Duration::from_secs(5), "took {took:?}");
    }
}
