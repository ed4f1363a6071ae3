//! Runs the job graph of a benchmark: every job a child `cnfmp` process with its own log,
//! `--jobs` at a time, each as soon as the jobs it needs have succeeded; finished outputs of
//! an earlier run are reused.

use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use crate::failure::Failure;

/// One child process of the run.
pub(super) struct Job {
    /// What it is, for progress lines ("train cnn-cnmp-low/cube_stacking").
    pub name: String,
    pub args: Vec<String>,
    /// What exists once it has succeeded (a directory or a file the child writes atomically).
    pub output: PathBuf,
    /// Where its stdout goes (kept only on success), if anywhere.
    pub stdout: Option<PathBuf>,
    pub log: PathBuf,
    /// Jobs that must succeed first (indices).
    pub needs: Vec<usize>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum State {
    Waiting,
    Running,
    Done,
    Reused,
    Failed,
}


/// Runs the plan, `parallel` jobs at a time, each as soon as what it needs has succeeded.
/// A job whose output exists is reused (unless `force`, which removes it first). A failed
/// job fails its dependents; the others go on, and the run fails at the end naming them.
pub(super) fn run_jobs(exe: &Path, plan: &[Job], parallel: usize, force: bool, started: Instant) -> Result<Vec<State>, Failure> {
    let mut run = Run { plan, states: mark_reused(plan, force)?, finished: 0, started };
    run.finished = run.states.iter().filter(|s| **s == State::Reused).count();
    if run.finished > 0 {
        eprintln!("{} reusing {} finished job(s) (--force redoes them)", run.stamp(), run.finished);
    }
    let mut running: Vec<(usize, Child, Instant)> = Vec::new();
    loop {
        run.skip_dependents_of_failures();
        while running.len() < parallel {
            let Some(index) = run.next_ready() else { break };
            let child = spawn(exe, &plan[index])?;
            run.states[index] = State::Running;
            eprintln!("{} started {}", run.stamp(), plan[index].name);
            running.push((index, child, Instant::now()));
        }
        if running.is_empty() {
            break;
        }
        std::thread::sleep(Duration::from_millis(200));
        let mut still = Vec::new();
        for (index, mut child, since) in running.drain(..) {
            let status = child
                .try_wait()
                .map_err(|err| Failure::Environment(format!("cannot wait for {}: {err}", plan[index].name)))?;
            match status {
                Some(status) => run.finish(index, status, since),
                None => still.push((index, child, since)),
            }
        }
        running = still;
    }
    let failed: Vec<&str> = (0..plan.len()).filter(|&i| run.states[i] == State::Failed).map(|i| plan[i].name.as_str()).collect();
    if !failed.is_empty() {
        return Err(Failure::Environment(format!(
            "{} of {} jobs failed or were skipped: {}; see the logs in {}",
            failed.len(),
            plan.len(),
            failed.join(", "),
            plan[0].log.parent().map_or_else(String::new, |p| p.display().to_string())
        )));
    }
    Ok(run.states)
}

/// Which jobs can be reused: a finished output is reused only when everything it was made
/// from was reused too (an evaluation of a model that is being retrained is stale). Outputs
/// that will be redone are removed. Jobs need only earlier jobs.
fn mark_reused(plan: &[Job], force: bool) -> Result<Vec<State>, Failure> {
    let mut states = vec![State::Waiting; plan.len()];
    for (index, job) in plan.iter().enumerate() {
        debug_assert!(job.needs.iter().all(|&n| n < index), "{} needs a later job", job.name);
        let inputs_reused = job.needs.iter().all(|&n| states[n] == State::Reused);
        if !force && inputs_reused && job.output.exists() {
            states[index] = State::Reused;
        } else {
            remove_output(&job.output)?;
        }
    }
    Ok(states)
}

/// The progress of a run: each job's state and how many have ended.
struct Run<'a> {
    plan: &'a [Job],
    states: Vec<State>,
    finished: usize,
    started: Instant,
}

impl Run<'_> {
    fn stamp(&self) -> String {
        format!("{:>5.0}s", self.started.elapsed().as_secs_f64())
    }

    /// Fails the waiting jobs that need a failed one.
    fn skip_dependents_of_failures(&mut self) {
        for index in 0..self.plan.len() {
            if self.states[index] == State::Waiting && self.plan[index].needs.iter().any(|&n| self.states[n] == State::Failed) {
                self.states[index] = State::Failed;
                self.finished += 1;
                eprintln!("{} [{}/{}] skipped {}: a job it needs failed", self.stamp(), self.finished, self.plan.len(), self.plan[index].name);
            }
        }
    }

    /// The first waiting job whose needs have all succeeded.
    fn next_ready(&self) -> Option<usize> {
        (0..self.plan.len()).find(|&i| {
            self.states[i] == State::Waiting && self.plan[i].needs.iter().all(|&n| matches!(self.states[n], State::Done | State::Reused))
        })
    }

    /// Records the end of job `index`: done when it exited well and left its output.
    fn finish(&mut self, index: usize, status: ExitStatus, since: Instant) {
        self.finished += 1;
        let job = &self.plan[index];
        let kept = job.stdout.as_ref().map_or(Ok(()), |path| keep_stdout(path, status.success()));
        if status.success() && job.output.exists() && kept.is_ok() {
            self.states[index] = State::Done;
            eprintln!("{} [{}/{}] done {} in {:.0} s", self.stamp(), self.finished, self.plan.len(), job.name, since.elapsed().as_secs_f64());
        } else {
            self.states[index] = State::Failed;
            eprintln!(
                "{} [{}/{}] FAILED {} ({status}); the end of {}:\n{}",
                self.stamp(),
                self.finished,
                self.plan.len(),
                job.name,
                job.log.display(),
                log_tail(&job.log)
            );
        }
    }
}

fn spawn(exe: &Path, job: &Job) -> Result<Child, Failure> {
    let open = |path: &Path| {
        fs::File::create(path).map_err(|err| Failure::Environment(format!("cannot create {}: {err}", path.display())))
    };
    let log = open(&job.log)?;
    let stdout = match &job.stdout {
        Some(path) => Stdio::from(open(&partial(path))?),
        None => Stdio::from(log.try_clone().map_err(|err| Failure::Environment(format!("cannot share the log: {err}")))?),
    };
    Command::new(exe)
        .args(&job.args)
        .stdin(Stdio::null())
        .stdout(stdout)
        .stderr(Stdio::from(log))
        // Jobs run side by side, one core each: neither inference nor training (which
        // otherwise uses every core) may start a second thread.
        .env("CNFMP_INFERENCE_THREADS", "1")
        .env("CNFMP_TORCH_THREADS", "1")
        .spawn()
        .map_err(|err| Failure::Environment(format!("cannot start {}: {err}", job.name)))
}

/// Where a job's stdout is written until it has succeeded.
fn partial(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".partial");
    path.with_file_name(name)
}

/// Moves a finished job's stdout into place, or drops it when the job failed.
fn keep_stdout(path: &Path, success: bool) -> Result<(), Failure> {
    let from = partial(path);
    if success {
        fs::rename(&from, path).map_err(|err| Failure::Environment(format!("cannot write {}: {err}", path.display())))
    } else {
        let _ = fs::remove_file(from);
        Ok(())
    }
}

pub(super) fn remove_output(path: &Path) -> Result<(), Failure> {
    let removed = if path.is_dir() {
        fs::remove_dir_all(path)
    } else if path.exists() {
        fs::remove_file(path)
    } else {
        Ok(())
    };
    removed.map_err(|err| Failure::Environment(format!("cannot remove the stale {}: {err}", path.display())))
}

/// The last lines of a log, indented.
fn log_tail(path: &Path) -> String {
    let text = fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(15)..].iter().map(|l| format!("    {l}")).collect::<Vec<_>>().join("\n")
}
