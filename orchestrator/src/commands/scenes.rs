//! The scenes of one `cnfmp predict --scenes` or `cnfmp segment --scenes` call: a directory
//! of scene folders (what `cnfmp sim render` writes) or a JSON lines file, listed and checked
//! before the interpreter starts, so a typo on line 90 fails in a second rather than after 89
//! predictions; then the loop over them in one warm process and its timings.

use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde::{Deserialize, Serialize};

use super::print_stdout;
use super::stats::quantile;
use crate::failure::Failure;
use crate::progress::Progress;

/// Image file names a scene folder may hold, in the order they are looked for.
const IMAGE_FILES: [&str; 3] = ["image.png", "image.jpg", "image.jpeg"];
/// The name of the batch's own report in the output directory; no scene may take it.
pub const SUMMARY_FILE: &str = "summary.json";

/// One scene: its name (its output in the output directory is named after it), its image and
/// where its objects come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SceneInput {
    pub name: String,
    pub image: PathBuf,
    pub objects: SceneObjects,
}

/// How a scene's objects are found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SceneObjects {
    /// Coarse masks (a label map) and the object names in label order.
    Masks { masks: PathBuf, names: ObjectNames },
    /// A prompt for the language segmenter.
    Prompt(String),
}

/// Object names: a file (a JSON list, or an object with an "objects" list), or given inline.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ObjectNames {
    File(PathBuf),
    Listed(Vec<String>),
}

/// What a scene must give besides its image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Needs {
    /// Coarse masks with the names of their labels, or else a prompt (`cnfmp predict`).
    MasksOrPrompt,
    /// A prompt (`cnfmp segment`); masks, if any, are not read.
    Prompt,
}

/// The scenes at `path`: a directory of scene folders or a `.jsonl` file (see the
/// `--scenes` help), each giving what `needs` says; a bad-input failure naming the first
/// problem otherwise.
pub fn list_scenes(path: &Path, needs: Needs) -> Result<Vec<SceneInput>, Failure> {
    let scenes = if path.is_dir() {
        list_folders(path, needs)?
    } else if path.is_file() {
        list_lines(path, needs)?
    } else {
        return Err(Failure::BadInput(format!("--scenes {} does not exist", path.display())));
    };
    if scenes.is_empty() {
        return Err(Failure::BadInput(format!("--scenes {} holds no scenes", path.display())));
    }
    let mut seen = HashSet::new();
    for scene in &scenes {
        check_name(&scene.name)?;
        if !seen.insert(scene.name.as_str()) {
            return Err(Failure::BadInput(format!("two scenes are named {:?}; names must be unique (each names its output)", scene.name)));
        }
    }
    Ok(scenes)
}

/// A scene folder: an image (`image.png`, `.jpg` or `.jpeg`), and `masks.png` with
/// `objects.json`, or else a prompt (`prompt.txt`, or the "prompt" of `objects.json`); only the
/// prompt when `needs` is [`Needs::Prompt`].
fn list_folders(dir: &Path, needs: Needs) -> Result<Vec<SceneInput>, Failure> {
    let entries = fs::read_dir(dir).map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", dir.display())))?;
    let mut folders: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.is_dir() && !path.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .collect();
    folders.sort();
    folders.iter().map(|folder| scene_folder(folder, needs)).collect()
}

fn scene_folder(folder: &Path, needs: Needs) -> Result<SceneInput, Failure> {
    let name = folder.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let image = IMAGE_FILES.iter().map(|file| folder.join(file)).find(|path| path.is_file()).ok_or_else(|| {
        Failure::BadInput(format!("scene folder {} has no image ({})", folder.display(), IMAGE_FILES.join(", ")))
    })?;
    let (masks, objects) = (folder.join("masks.png"), folder.join("objects.json"));
    let objects = if needs == Needs::MasksOrPrompt && masks.is_file() {
        if !objects.is_file() {
            return Err(Failure::BadInput(format!("scene folder {} has masks.png but no objects.json naming its labels", folder.display())));
        }
        SceneObjects::Masks { masks, names: ObjectNames::File(objects) }
    } else if let Some(prompt) = folder_prompt(folder, &objects)? {
        SceneObjects::Prompt(prompt)
    } else if needs == Needs::Prompt {
        return Err(Failure::BadInput(format!("scene folder {} has no prompt (prompt.txt, or \"prompt\" in objects.json)", folder.display())));
    } else {
        return Err(Failure::BadInput(format!(
            "scene folder {} has neither masks.png with objects.json nor a prompt (prompt.txt, or \"prompt\" in objects.json)",
            folder.display()
        )));
    };
    Ok(SceneInput { name, image, objects })
}

fn folder_prompt(folder: &Path, objects: &Path) -> Result<Option<String>, Failure> {
    let text_file = folder.join("prompt.txt");
    if text_file.is_file() {
        let text = fs::read_to_string(&text_file).map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", text_file.display())))?;
        return Ok(Some(text.trim().to_owned()));
    }
    if !objects.is_file() {
        return Ok(None);
    }
    let text = fs::read_to_string(objects).map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", objects.display())))?;
    let value: serde_json::Value =
        serde_json::from_str(&text).map_err(|err| Failure::BadInput(format!("{} is not JSON: {err}", objects.display())))?;
    Ok(value.get("prompt").and_then(serde_json::Value::as_str).map(str::to_owned))
}

/// One line of a scenes file. Paths are relative to the file's directory.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneLine {
    name: Option<String>,
    image: PathBuf,
    masks: Option<PathBuf>,
    objects: Option<ObjectsField>,
    prompt: Option<String>,
}

#[derive(Debug, Deserialize)]
#[serde(untagged)]
enum ObjectsField {
    Listed(Vec<String>),
    File(PathBuf),
}

fn list_lines(file: &Path, needs: Needs) -> Result<Vec<SceneInput>, Failure> {
    let text = fs::read_to_string(file).map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", file.display())))?;
    let base = file.parent().unwrap_or(Path::new("."));
    let mut scenes = Vec::new();
    for (index, line) in text.lines().enumerate().filter(|(_, line)| !line.trim().is_empty()) {
        let at = |message: String| Failure::BadInput(format!("{} line {}: {message}", file.display(), index + 1));
        let line: SceneLine = serde_json::from_str(line).map_err(|err| {
            at(format!("{err} (expected {{\"image\": PATH, \"masks\": PATH, \"objects\": [NAMES] or PATH}} or {{\"image\": PATH, \"prompt\": TEXT}})"))
        })?;
        let resolve = |path: &Path| if path.is_absolute() { path.to_path_buf() } else { base.join(path) };
        let image = resolve(&line.image);
        if !image.is_file() {
            return Err(at(format!("image {} does not exist", image.display())));
        }
        let objects = match (line.masks, line.objects, line.prompt) {
            (_, _, Some(prompt)) if needs == Needs::Prompt => SceneObjects::Prompt(prompt),
            (_, _, None) if needs == Needs::Prompt => return Err(at("give a \"prompt\": the segmenter finds what it names".into())),
            (Some(masks), Some(objects), _) => {
                let masks = resolve(&masks);
                if !masks.is_file() {
                    return Err(at(format!("masks {} does not exist", masks.display())));
                }
                let names = match objects {
                    ObjectsField::Listed(names) => ObjectNames::Listed(names),
                    ObjectsField::File(path) if resolve(&path).is_file() => ObjectNames::File(resolve(&path)),
                    ObjectsField::File(path) => return Err(at(format!("objects {} does not exist", resolve(&path).display()))),
                };
                SceneObjects::Masks { masks, names }
            }
            (Some(_), None, _) => return Err(at("\"masks\" needs \"objects\", the names of its labels in order".into())),
            (None, _, Some(prompt)) => SceneObjects::Prompt(prompt),
            (None, _, None) => return Err(at("give \"masks\" with \"objects\", or a \"prompt\"".into())),
        };
        let name = line.name.unwrap_or_else(|| format!("scene-{:04}", scenes.len() + 1));
        scenes.push(SceneInput { name, image, objects });
    }
    Ok(scenes)
}

/// A scene name is a plain file name: its output is `<name>.json` (a trajectory) or `<name>/`
/// (a segmentation), beside summary.json.
fn check_name(name: &str) -> Result<(), Failure> {
    let plain = !name.is_empty() && !name.starts_with('.') && !name.contains(['/', '\\']) && name.len() <= 200;
    if !plain || format!("{name}.json") == SUMMARY_FILE {
        return Err(Failure::BadInput(format!(
            "scene name {name:?} cannot name a file in the output directory (no slashes, no leading dot, not \"summary\")"
        )));
    }
    Ok(())
}

/// One scene of a batch: what the work on it returned, or the bad-input message that kept it
/// from finishing, and its wall time.
pub struct SceneOutcome<'a, T> {
    pub scene: &'a SceneInput,
    pub result: Result<T, String>,
    /// Wall time of the scene (ms): reading its files, the work, writing its outputs.
    pub latency_ms: f64,
}

/// Runs `work` on every scene in turn in this process, with a progress bar labelled `label`.
/// A scene's bad input (its files, a prompt not grounded: `Failure::BadInput`) is noted as
/// "<name>: <failed>: <message>" and the batch goes on; any other failure (the environment
/// broke, not the scene) stops it, and comes back with the outcomes so far.
pub fn for_each_scene<'a, T>(
    label: &str,
    failed: &str,
    scenes: &'a [SceneInput],
    mut work: impl FnMut(&SceneInput) -> Result<T, Failure>,
) -> (Vec<SceneOutcome<'a, T>>, Result<(), Failure>) {
    let mut progress = Progress::new(label, scenes.len() as u64, 0);
    let mut outcomes = Vec::with_capacity(scenes.len());
    let mut stopped = Ok(());
    for scene in scenes {
        let call = Instant::now();
        let result = match work(scene) {
            Ok(done) => Ok(done),
            Err(Failure::BadInput(message)) => {
                progress.note(&format!("{}: {failed}: {message}", scene.name));
                Err(message)
            }
            Err(failure) => {
                stopped = Err(failure);
                break;
            }
        };
        outcomes.push(SceneOutcome { scene, result, latency_ms: call.elapsed().as_secs_f64() * 1e3 });
        progress.advance(1);
    }
    progress.finish();
    (outcomes, stopped)
}

/// The timings of a batch, as its summary.json reports them.
#[derive(Debug, Serialize)]
pub struct BatchTimings {
    /// From the command's start to the last scene done (s).
    pub wall_time_s: f64,
    /// Start-up paid once (s): listing the scenes, starting the interpreter, the imports and
    /// loading what the scenes share, i.e. the time before the first scene plus its latency
    /// less the warm median.
    pub startup_s: f64,
    /// Over every scene done but the first (which pays the start-up).
    pub latency_ms_p50: f64,
    pub latency_ms_p95: f64,
}

impl BatchTimings {
    /// The timings of a batch that started at `started`, began its first scene at
    /// `loop_started`, and took `latencies_ms` for the scenes it finished, in order (the
    /// scenes refused before reaching the model say nothing about its speed).
    pub fn new(latencies_ms: &[f64], started: Instant, loop_started: Instant) -> Self {
        let warm = &latencies_ms[usize::from(latencies_ms.len() > 1)..];
        let warm_p50 = quantile(warm, 0.5);
        BatchTimings {
            wall_time_s: started.elapsed().as_secs_f64(),
            startup_s: latencies_ms
                .first()
                .map_or(f64::NAN, |first| (loop_started - started).as_secs_f64() + (first - warm_p50).max(0.0) / 1e3),
            latency_ms_p50: warm_p50,
            latency_ms_p95: quantile(warm, 0.95),
        }
    }
}

/// How a batch ends once its outputs are written: a line on stdout (`who`: how many scenes
/// were `done`, e.g. "predicted", the timings, and where `outputs` and summary.json are), then
/// Ok when every scene was done, else a bad-input failure (exit code 2) saying how many were
/// not, the first and why. `errors` holds each scene's name and error, if any.
pub fn end_batch(who: &str, done: &str, outputs: &str, out: &Path, timings: &BatchTimings, errors: &[(&str, Option<&str>)]) -> Result<(), Failure> {
    let failed: Vec<(&str, &str)> = errors.iter().filter_map(|&(name, error)| error.map(|error| (name, error))).collect();
    print_stdout(&format!(
        "{who}: {} of {} scenes {done} in {:.1} s (start-up {:.1} s, then p50 {:.0} ms / p95 {:.0} ms per scene); {outputs} and {SUMMARY_FILE} in {}",
        errors.len() - failed.len(),
        errors.len(),
        timings.wall_time_s,
        timings.startup_s,
        timings.latency_ms_p50,
        timings.latency_ms_p95,
        out.display()
    ))?;
    match failed.first() {
        None => Ok(()),
        Some((name, error)) => Err(Failure::BadInput(format!(
            "{} of {} scenes were not {done} (first {name}: {error}); see {}",
            failed.len(),
            errors.len(),
            out.join(SUMMARY_FILE).display()
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(path: &Path, contents: &str) {
        fs::create_dir_all(path.parent().unwrap()).unwrap();
        fs::write(path, contents).unwrap();
    }

    #[test]
    fn scene_folders_take_masks_first_then_a_prompt() {
        let dir = tempfile::tempdir().unwrap();
        write(&dir.path().join("b/image.png"), "");
        write(&dir.path().join("b/masks.png"), "");
        write(&dir.path().join("b/objects.json"), r#"{"objects": ["cup"], "prompt": "ignored"}"#);
        write(&dir.path().join("a/image.jpg"), "");
        write(&dir.path().join("a/objects.json"), r#"{"prompt": "put the cup on the plate"}"#);
        write(&dir.path().join("c/image.png"), "");
        write(&dir.path().join("c/prompt.txt"), "stack the cups\n");
        write(&dir.path().join("notes.txt"), "not a scene");
        let scenes = list_scenes(dir.path(), Needs::MasksOrPrompt).unwrap();
        assert_eq!(scenes.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["a", "b", "c"]);
        assert_eq!(scenes[0].objects, SceneObjects::Prompt("put the cup on the plate".into()));
        assert!(matches!(&scenes[1].objects, SceneObjects::Masks { names: ObjectNames::File(_), .. }));
        assert_eq!(scenes[2].objects, SceneObjects::Prompt("stack the cups".into()));
        write(&dir.path().join("d/image.png"), "");
        let err = list_scenes(dir.path(), Needs::MasksOrPrompt).unwrap_err().to_string();
        assert!(err.contains("d has neither masks.png"), "{err}");
    }

    #[test]
    fn segmenting_takes_a_prompt_even_beside_masks_and_refuses_a_scene_without_one() {
        let dir = tempfile::tempdir().unwrap();
        write(&dir.path().join("a/image.png"), "");
        write(&dir.path().join("a/masks.png"), "");
        write(&dir.path().join("a/objects.json"), r#"{"objects": ["cup", "plate"], "prompt": "put the cup on the plate"}"#);
        write(&dir.path().join("b/image.jpg"), "");
        write(&dir.path().join("b/prompt.txt"), "stack the cups\n");
        let scenes = list_scenes(dir.path(), Needs::Prompt).unwrap();
        assert_eq!(scenes[0].objects, SceneObjects::Prompt("put the cup on the plate".into()));
        assert_eq!(scenes[1].objects, SceneObjects::Prompt("stack the cups".into()));
        write(&dir.path().join("c/image.png"), "");
        write(&dir.path().join("c/masks.png"), "");
        write(&dir.path().join("c/objects.json"), r#"["cup"]"#);
        assert!(list_scenes(dir.path(), Needs::MasksOrPrompt).is_ok(), "masks are enough to predict");
        let err = list_scenes(dir.path(), Needs::Prompt).unwrap_err().to_string();
        assert!(err.contains("c has no prompt"), "{err}");

        let file = dir.path().join("scenes.jsonl");
        write(&file, "{\"image\": \"a/image.png\", \"masks\": \"a/masks.png\", \"objects\": [\"cup\"], \"prompt\": \"the cup\"}\n");
        assert_eq!(list_scenes(&file, Needs::Prompt).unwrap()[0].objects, SceneObjects::Prompt("the cup".into()));
        write(&file, "{\"image\": \"a/image.png\", \"masks\": \"a/masks.png\", \"objects\": [\"cup\"]}\n");
        let err = list_scenes(&file, Needs::Prompt).unwrap_err().to_string();
        assert!(err.contains("line 1: give a \"prompt\""), "{err}");
    }

    #[test]
    fn batch_timings_leave_the_first_scene_out_of_the_warm_latency() {
        let started = Instant::now();
        let loop_started = started + std::time::Duration::from_secs(2);
        let timings = BatchTimings::new(&[1500.0, 100.0, 200.0, 300.0], started, loop_started);
        assert_eq!(timings.latency_ms_p50, 200.0);
        assert!((timings.startup_s - 3.3).abs() < 1e-9, "{}", timings.startup_s);
        assert!(BatchTimings::new(&[], started, loop_started).startup_s.is_nan());
    }

    #[test]
    fn scene_lines_resolve_paths_and_name_the_line_of_a_mistake() {
        let dir = tempfile::tempdir().unwrap();
        write(&dir.path().join("x/image.png"), "");
        write(&dir.path().join("x/masks.png"), "");
        let file = dir.path().join("scenes.jsonl");
        write(&file, "{\"image\": \"x/image.png\", \"masks\": \"x/masks.png\", \"objects\": [\"cup\", \"plate\"]}\n\n{\"name\": \"p\", \"image\": \"x/image.png\", \"prompt\": \"put the cup on the plate\"}\n");
        let scenes = list_scenes(&file, Needs::MasksOrPrompt).unwrap();
        assert_eq!(scenes[0].name, "scene-0001");
        assert_eq!(scenes[0].image, dir.path().join("x/image.png"));
        assert_eq!(scenes[0].objects, SceneObjects::Masks { masks: dir.path().join("x/masks.png"), names: ObjectNames::Listed(vec!["cup".into(), "plate".into()]) });
        assert_eq!(scenes[1].objects, SceneObjects::Prompt("put the cup on the plate".into()));
        for (line, needle) in [
            ("{\"image\": \"x/image.png\", \"mask\": \"x/masks.png\"}", "unknown field `mask`"),
            ("{\"image\": \"x/missing.png\", \"prompt\": \"p\"}", "does not exist"),
            ("{\"image\": \"x/image.png\", \"masks\": \"x/masks.png\"}", "needs \"objects\""),
            ("{\"image\": \"x/image.png\"}", "or a \"prompt\""),
            ("{\"name\": \"../up\", \"image\": \"x/image.png\", \"prompt\": \"p\"}", "cannot name a file"),
            ("{\"name\": \"summary\", \"image\": \"x/image.png\", \"prompt\": \"p\"}", "cannot name a file"),
            ("not json", "line 2"),
        ] {
            write(&file, &format!("{{\"image\": \"x/image.png\", \"prompt\": \"p\"}}\n{line}\n"));
            let err = list_scenes(&file, Needs::MasksOrPrompt).unwrap_err().to_string();
            assert!(err.contains(needle), "{line}: {err}");
        }
        write(&file, "{\"name\": \"a\", \"image\": \"x/image.png\", \"prompt\": \"p\"}\n{\"name\": \"a\", \"image\": \"x/image.png\", \"prompt\": \"p\"}\n");
        assert!(list_scenes(&file, Needs::MasksOrPrompt).unwrap_err().to_string().contains("two scenes are named"));
        write(&file, "\n");
        assert!(list_scenes(&file, Needs::MasksOrPrompt).unwrap_err().to_string().contains("holds no scenes"));
    }
}
