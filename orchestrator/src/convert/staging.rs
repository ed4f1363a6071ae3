//! The staging area of a conversion (`.<out name>.convert` beside `--out`) and the worker
//! pool that fills it. Layout:
//!
//! ```text
//! lock            held (flock) while a conversion runs: two runs never share an area
//! plan.json       what is being converted; a rerun must ask for the same
//! work/<k>/       episode k being staged (incomplete; cleared on start)
//! episodes/<k>/   episode k staged completely (renamed from work/, so never partial)
//! output/         the output being assembled; renamed to --out when complete
//! ```

use std::fs::File;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::mpsc;

use super::episode::EpisodeError;
use super::job::{ConvertReport, Plan, REPORT_FILE};
use crate::failure::Failure;
use crate::files::write_atomically;
use crate::progress::Progress;
use segmenter_bridge::SkippedEpisode;

/// An open, locked staging area.
pub struct Staging {
    root: PathBuf,
    /// Held for the life of the conversion (the lock is released when the file closes).
    _lock: File,
}

fn io_failure(what: &str, path: &Path, err: std::io::Error) -> Failure {
    Failure::Environment(format!("cannot {what} {}: {err}", path.display()))
}

impl Staging {
    /// Opens (creating or resuming) the staging area for output `out`.
    pub fn open(out: &Path, plan: &Plan) -> Result<Self, Failure> {
        let out = std::path::absolute(out).map_err(|err| io_failure("resolve", out, err))?;
        let name = out.file_name().ok_or_else(|| Failure::BadInput(format!("--out {} has no folder name", out.display())))?;
        let parent = out.parent().unwrap_or(Path::new("/"));
        std::fs::create_dir_all(parent).map_err(|err| io_failure("create", parent, err))?;
        let root = parent.join(format!(".{}.convert", name.to_string_lossy()));
        std::fs::create_dir_all(&root).map_err(|err| io_failure("create", &root, err))?;
        let lock = File::create(root.join("lock")).map_err(|err| io_failure("create", &root.join("lock"), err))?;
        if lock.try_lock().is_err() {
            return Err(Failure::BadInput(format!("another conversion into {} is running (it holds {})", out.display(), root.join("lock").display())));
        }
        let plan_path = root.join("plan.json");
        if plan_path.exists() {
            let text = std::fs::read_to_string(&plan_path).map_err(|err| io_failure("read", &plan_path, err))?;
            match serde_json::from_str::<Plan>(&text) {
                Ok(previous) if previous == *plan => eprintln!("resuming the interrupted conversion in {}", root.display()),
                Ok(previous) => {
                    return Err(Failure::BadInput(format!(
                        "{} holds an interrupted conversion of {} ({} episodes at {} fps) into {}; rerun that conversion to finish it, or delete the folder to start this one",
                        root.display(), previous.source, previous.episodes.len(), previous.fps, out.display()
                    )));
                }
                Err(err) => return Err(Failure::BadInput(format!("{} is damaged ({err}); delete {} and rerun", plan_path.display(), root.display()))),
            }
        } else {
            write_atomically(&plan_path, serde_json::to_string_pretty(plan).expect("plan serialises").as_bytes())?;
        }
        for dir in ["work", "output"] {
            let path = root.join(dir);
            if path.exists() {
                std::fs::remove_dir_all(&path).map_err(|err| io_failure("clear", &path, err))?;
            }
        }
        for dir in ["work", "episodes"] {
            std::fs::create_dir_all(root.join(dir)).map_err(|err| io_failure("create", &root.join(dir), err))?;
        }
        Ok(Staging { root, _lock: lock })
    }

    /// Where complete staged episodes live (`episodes/<k>`).
    pub fn episodes_dir(&self) -> PathBuf {
        self.root.join("episodes")
    }

    fn staged(&self, index: usize) -> PathBuf {
        self.episodes_dir().join(format!("{index:06}"))
    }

    /// Folder names of the staged episodes, in plan order.
    pub fn staged_names(&self, plan: &Plan) -> Vec<String> {
        (0..plan.episodes.len()).filter(|&k| self.staged(k).is_dir()).map(|k| format!("{k:06}")).collect()
    }

    /// Where the output is assembled; it does not exist yet.
    pub fn output_dir(&self) -> PathBuf {
        self.root.join("output")
    }

    /// Moves the staged episode folders into the output under their names (raw export) and
    /// returns the indices of the episodes moved.
    pub fn move_staged_to_output(&self, plan: &Plan) -> Result<Vec<usize>, Failure> {
        let output = self.output_dir();
        std::fs::create_dir_all(&output).map_err(|err| io_failure("create", &output, err))?;
        let mut moved = Vec::new();
        for (k, name) in plan.episodes.iter().enumerate() {
            let staged = self.staged(k);
            if staged.is_dir() {
                std::fs::rename(&staged, output.join(name)).map_err(|err| io_failure("move", &staged, err))?;
                moved.push(k);
            }
        }
        Ok(moved)
    }

    /// Writes the report into the assembled output, renames it to `out` and removes the
    /// staging area: the output appears complete or not at all.
    pub fn publish(self, report: &ConvertReport, out: &Path) -> Result<(), Failure> {
        let output = self.output_dir();
        let text = serde_json::to_string_pretty(report).expect("report serialises") + "\n";
        write_atomically(&output.join(REPORT_FILE), text.as_bytes())?;
        if out.exists() {
            return Err(Failure::BadInput(format!("{} appeared while converting; the result stays in {}", out.display(), output.display())));
        }
        std::fs::rename(&output, out).map_err(|err| io_failure("move the result to", out, err))?;
        std::fs::remove_dir_all(&self.root).map_err(|err| io_failure("remove", &self.root, err))
    }
}

/// What staging did.
pub struct StageOutcome {
    /// Bad episodes in plan order.
    pub skipped: Vec<SkippedEpisode>,
    /// Episodes already staged by an interrupted run.
    pub resumed: u64,
}

/// Stages every episode of `plan` not staged yet with `workers` threads running
/// `stage_one(index, empty work folder)`. Bad episodes are collected (or, when `strict`,
/// the first one stops the run); a fatal error stops it.
pub fn stage_all<F>(staging: &Staging, plan: &Plan, workers: usize, strict: bool, stage_one: &F) -> Result<StageOutcome, Failure>
where
    F: Fn(usize, &Path) -> Result<(), EpisodeError> + Sync,
{
    let pending: Vec<usize> = (0..plan.episodes.len()).filter(|&k| !staging.staged(k).is_dir()).collect();
    let resumed = (plan.episodes.len() - pending.len()) as u64;
    let mut progress = Progress::new("staging", plan.episodes.len() as u64, resumed);
    let (cursor, stop) = (AtomicUsize::new(0), AtomicBool::new(false));
    let (results, received) = mpsc::channel::<(usize, Result<(), EpisodeError>)>();
    let mut skipped: Vec<(usize, SkippedEpisode)> = Vec::new();
    let mut failure: Option<Failure> = None;
    std::thread::scope(|scope| {
        for _ in 0..workers.clamp(1, pending.len().max(1)) {
            let results = results.clone();
            let (cursor, stop, pending) = (&cursor, &stop, &pending);
            scope.spawn(move || {
                while !stop.load(Ordering::Relaxed) {
                    let Some(&k) = pending.get(cursor.fetch_add(1, Ordering::Relaxed)) else { break };
                    let work = staging.root.join("work").join(format!("{k:06}"));
                    let result = std::fs::create_dir(&work)
                        .map_err(|err| EpisodeError::Fatal(io_failure("create", &work, err)))
                        .and_then(|()| stage_one(k, &work))
                        .and_then(|()| std::fs::rename(&work, staging.staged(k)).map_err(|err| EpisodeError::Fatal(io_failure("move", &work, err))));
                    if result.is_err() {
                        let _ = std::fs::remove_dir_all(&work);
                    }
                    if results.send((k, result)).is_err() {
                        break;
                    }
                }
            });
        }
        drop(results);
        for (k, result) in received {
            progress.advance(1);
            match result {
                Ok(()) => {}
                Err(EpisodeError::Bad(bad)) if !strict => skipped.push((k, bad)),
                Err(EpisodeError::Bad(bad)) => {
                    stop.store(true, Ordering::Relaxed);
                    failure.get_or_insert(Failure::BadInput(format!(
                        "episode {} is bad (--strict): {}: {}; fix it and rerun to continue where this run stopped",
                        bad.episode, bad.file, bad.reason
                    )));
                }
                Err(EpisodeError::Fatal(fatal)) => {
                    stop.store(true, Ordering::Relaxed);
                    failure.get_or_insert(fatal);
                }
            }
        }
    });
    progress.finish();
    if let Some(failure) = failure {
        return Err(failure);
    }
    skipped.sort_by_key(|(k, _)| *k);
    for (_, bad) in &skipped {
        eprintln!("skipped {}: {}: {}", bad.episode, bad.file, bad.reason);
    }
    Ok(StageOutcome { skipped: skipped.into_iter().map(|(_, bad)| bad).collect(), resumed })
}
