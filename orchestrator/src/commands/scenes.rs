//! The scenes of one `cnfmp predict --scenes` call: a directory of scene folders (what
//! `cnfmp sim render` writes) or a JSON lines file, listed and checked before the interpreter
//! starts, so a typo on line 90 fails in a second rather than after 89 predictions.

use std::collections::HashSet;
use std::fs;
use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::failure::Failure;

/// Image file names a scene folder may hold, in the order they are looked for.
const IMAGE_FILES: [&str; 3] = ["image.png", "image.jpg", "image.jpeg"];
/// The name of the batch's own report in the output directory; no scene may take it.
pub const SUMMARY_FILE: &str = "summary.json";

/// One scene to predict: its name (the output is `<name>.json`), its image and where its
/// objects come from.
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

/// The scenes at `path`: a directory of scene folders or a `.jsonl` file (see the
/// `--scenes` help); a bad-input failure naming the first problem otherwise.
pub fn list_scenes(path: &Path) -> Result<Vec<SceneInput>, Failure> {
    let scenes = if path.is_dir() {
        list_folders(path)?
    } else if path.is_file() {
        list_lines(path)?
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
            return Err(Failure::BadInput(format!("two scenes are named {:?}; names must be unique (each becomes <name>.json)", scene.name)));
        }
    }
    Ok(scenes)
}

/// A scene folder: an image (`image.png`, `.jpg` or `.jpeg`), and `masks.png` with
/// `objects.json`, or else a prompt (`prompt.txt`, or the "prompt" of `objects.json`).
fn list_folders(dir: &Path) -> Result<Vec<SceneInput>, Failure> {
    let entries = fs::read_dir(dir).map_err(|err| Failure::BadInput(format!("cannot read {}: {err}", dir.display())))?;
    let mut folders: Vec<PathBuf> = entries
        .filter_map(Result::ok)
        .map(|entry| entry.path())
        .filter(|path| path.is_dir() && !path.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.')))
        .collect();
    folders.sort();
    folders.iter().map(|folder| scene_folder(folder)).collect()
}

fn scene_folder(folder: &Path) -> Result<SceneInput, Failure> {
    let name = folder.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
    let image = IMAGE_FILES.iter().map(|file| folder.join(file)).find(|path| path.is_file()).ok_or_else(|| {
        Failure::BadInput(format!("scene folder {} has no image ({})", folder.display(), IMAGE_FILES.join(", ")))
    })?;
    let (masks, objects) = (folder.join("masks.png"), folder.join("objects.json"));
    let objects = if masks.is_file() {
        if !objects.is_file() {
            return Err(Failure::BadInput(format!("scene folder {} has masks.png but no objects.json naming its labels", folder.display())));
        }
        SceneObjects::Masks { masks, names: ObjectNames::File(objects) }
    } else if let Some(prompt) = folder_prompt(folder, &objects)? {
        SceneObjects::Prompt(prompt)
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

fn list_lines(file: &Path) -> Result<Vec<SceneInput>, Failure> {
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

/// A scene name is a plain file name: its trajectory is written to `<name>.json`.
fn check_name(name: &str) -> Result<(), Failure> {
    let plain = !name.is_empty() && !name.starts_with('.') && !name.contains(['/', '\\']) && name.len() <= 200;
    if !plain || format!("{name}.json") == SUMMARY_FILE {
        return Err(Failure::BadInput(format!(
            "scene name {name:?} cannot name a file in the output directory (no slashes, no leading dot, not \"summary\")"
        )));
    }
    Ok(())
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
        let scenes = list_scenes(dir.path()).unwrap();
        assert_eq!(scenes.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["a", "b", "c"]);
        assert_eq!(scenes[0].objects, SceneObjects::Prompt("put the cup on the plate".into()));
        assert!(matches!(&scenes[1].objects, SceneObjects::Masks { names: ObjectNames::File(_), .. }));
        assert_eq!(scenes[2].objects, SceneObjects::Prompt("stack the cups".into()));
        write(&dir.path().join("d/image.png"), "");
        let err = list_scenes(dir.path()).unwrap_err().to_string();
        assert!(err.contains("d has neither masks.png"), "{err}");
    }

    #[test]
    fn scene_lines_resolve_paths_and_name_the_line_of_a_mistake() {
        let dir = tempfile::tempdir().unwrap();
        write(&dir.path().join("x/image.png"), "");
        write(&dir.path().join("x/masks.png"), "");
        let file = dir.path().join("scenes.jsonl");
        write(&file, "{\"image\": \"x/image.png\", \"masks\": \"x/masks.png\", \"objects\": [\"cup\", \"plate\"]}\n\n{\"name\": \"p\", \"image\": \"x/image.png\", \"prompt\": \"put the cup on the plate\"}\n");
        let scenes = list_scenes(&file).unwrap();
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
            let err = list_scenes(&file).unwrap_err().to_string();
            assert!(err.contains(needle), "{line}: {err}");
        }
        write(&file, "{\"name\": \"a\", \"image\": \"x/image.png\", \"prompt\": \"p\"}\n{\"name\": \"a\", \"image\": \"x/image.png\", \"prompt\": \"p\"}\n");
        assert!(list_scenes(&file).unwrap_err().to_string().contains("two scenes are named"));
        write(&file, "\n");
        assert!(list_scenes(&file).unwrap_err().to_string().contains("holds no scenes"));
    }
}
