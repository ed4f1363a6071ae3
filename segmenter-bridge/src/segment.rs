//! Typed calls into the language-conditioned segmenter (`cnfmp.segmenter.api`): segment a
//! scene image for a prompt, train the `film` backend, evaluate a backend on held-out renders.

use std::path::PathBuf;

use pyo3::prelude::*;
use pyo3::types::PyBytes;
use serde::{Deserialize, Serialize};

use crate::error::BridgeError;
use crate::sim::{batch_items, item, one_per_item};
use crate::worker::Bridge;

/// What `cnfmp segment` (and prediction from a prompt) asks for.
#[derive(Debug, Clone)]
pub struct SegmentRequest {
    /// The encoded scene image (PNG, JPEG, ...).
    pub image: Vec<u8>,
    pub prompt: String,
    /// auto | film | clipseg | owlv2-sam | color.
    pub backend: String,
    /// Weights directory of the backend (default: its own default location).
    pub weights: Option<PathBuf>,
    /// Order the label map for a core model whose object slots take these prompt roles, in
    /// order (label k = the phrase of the k-th role; see `ModelDescription::roles`).
    pub roles: Option<Vec<String>>,
    /// Also encode the per-phrase mask PNGs and the overlay (false leaves them empty).
    pub pictures: bool,
}

/// One phrase of the prompt and what was found for it.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct SegmentedObject {
    pub phrase: String,
    /// target | destination | obstacle | object | unknown.
    pub role: String,
    pub category: Option<String>,
    pub colour: Option<String>,
    pub found: bool,
    /// Mean mask probability in [0, 1] (the peak probability when nothing was found).
    pub score: f64,
    /// Mask area (px).
    pub area: u64,
    /// [x0, y0, x1, y1) in pixels.
    pub bbox: Option<[u32; 4]>,
    /// [x, y] in pixels.
    pub centroid: Option<[f64; 2]>,
    /// Label of this phrase in the unordered label map (1-based).
    pub label: u32,
}

/// Which phrase fills a model's object slot.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct SlotAssignment {
    pub slot: u32,
    pub label: u32,
    pub role: String,
    pub phrase: String,
}

/// The JSON document of a segmentation.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SegmentDocument {
    pub prompt: String,
    pub backend: String,
    /// [height, width] (px).
    pub image_size: [u32; 2],
    pub found: u32,
    pub nothing_found: bool,
    pub objects: Vec<SegmentedObject>,
    /// Only when a task was given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slots: Option<Vec<SlotAssignment>>,
    /// Stage timings (ms): parse, ground, postprocess, total.
    pub timings_ms: serde_json::Map<String, serde_json::Value>,
}

/// A segmentation with its pictures.
#[derive(Debug, Clone)]
pub struct Segmentation {
    pub document: SegmentDocument,
    /// 8-bit label map PNG (slot order when a task was given, phrase order otherwise).
    pub labels_png: Vec<u8>,
    /// One 0/255 mask PNG per phrase, in phrase order (empty unless pictures were asked for).
    pub mask_pngs: Vec<Vec<u8>>,
    /// The image with the masks drawn on it (PNG; empty unless pictures were asked for).
    pub overlay_png: Vec<u8>,
    /// The phrases in label-map order (the object names a core model gets).
    pub slot_names: Vec<String>,
}

/// A segmentation as Python returns it: the JSON document, the label map, the per-phrase
/// masks, the overlay and the slot names.
type RawSegmentation = (String, Vec<u8>, Vec<Vec<u8>>, Vec<u8>, Vec<String>);

/// What `cnfmp segmenter train` asks for.
#[derive(Debug, Clone)]
pub struct SegmenterTrainRequest {
    pub out: PathBuf,
    pub config: Option<PathBuf>,
    pub steps: Option<u64>,
    pub seed: Option<u64>,
    /// Multiplies every task's number of training scenes.
    pub scenes_scale: Option<f64>,
    /// The command line, recorded in the card.
    pub command: String,
}

impl Bridge {
    /// Segments `request.image` for `request.prompt` (`cnfmp.segmenter.api.segment`).
    pub fn segment(&self, request: SegmentRequest) -> Result<Segmentation, BridgeError> {
        let mut answers = self.segment_batch(vec![request])?;
        answers.pop().unwrap_or_else(|| Err(BridgeError::Protocol("cnfmp.segmenter.api.segment_batch answered nothing".into())))
    }

    /// Segments several images in one call, side by side on Python's worker pool
    /// (`cnfmp.segmenter.api.segment_batch`). One result per request, in order: a request's
    /// bad input (or a prompt not grounded) fails that request alone; the outer error is for
    /// the whole call.
    pub fn segment_batch(&self, requests: Vec<SegmentRequest>) -> Result<Vec<Result<Segmentation, BridgeError>>, BridgeError> {
        let count = requests.len();
        let answers = self.call(move |py| {
            let run = || -> PyResult<Vec<Result<RawSegmentation, BridgeError>>> {
                let mut arguments = Vec::with_capacity(count);
                for request in requests {
                    arguments.push(kwargs!(py,
                        image_data = PyBytes::new(py, &request.image),
                        prompt = request.prompt,
                        backend_name = request.backend,
                        weights = request.weights,
                        roles = request.roles,
                        pictures = request.pictures,
                    ));
                }
                let answers = py.import("cnfmp.segmenter.api")?.call_method1("segment_batch", (arguments,))?;
                batch_items(py, &answers, |answer| {
                    let dict = answer.cast::<pyo3::types::PyDict>()?;
                    Ok((
                        item(dict, "json")?.extract::<String>()?,
                        item(dict, "labels_png")?.extract::<Vec<u8>>()?,
                        item(dict, "mask_pngs")?.extract::<Vec<Vec<u8>>>()?,
                        item(dict, "overlay_png")?.extract::<Vec<u8>>()?,
                        item(dict, "slot_names")?.extract::<Vec<String>>()?,
                    ))
                })
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })?;
        Ok(one_per_item(answers, count, "cnfmp.segmenter.api.segment_batch")?
            .into_iter()
            .map(|answer| {
                let (document, labels_png, mask_pngs, overlay_png, slot_names) = answer?;
                let document = serde_json::from_str(&document)
                    .map_err(|err| BridgeError::Protocol(format!("cnfmp.segmenter.api.segment: {err}")))?;
                Ok(Segmentation { document, labels_png, mask_pngs, overlay_png, slot_names })
            })
            .collect())
    }

    /// Loads segmenter `backend` (weights from `weights` or its default location) and warms
    /// it up on a blank image (`cnfmp.segmenter.api.preload`). Returns the backend's name
    /// (what `auto` resolved to).
    pub fn segmenter_preload(&self, backend: &str, weights: Option<PathBuf>) -> Result<String, BridgeError> {
        let backend = backend.to_owned();
        self.call(move |py| {
            let run = || -> PyResult<String> {
                let kwargs = kwargs!(py, name = backend, weights = weights);
                py.import("cnfmp.segmenter.api")?.call_method("preload", (), Some(&kwargs))?.extract()
            };
            run().map_err(|err| BridgeError::python(py, &err))
        })
    }

    /// Trains the film segmenter (`cnfmp.segmenter.api.train`); progress on stderr. Returns
    /// the summary JSON.
    pub fn segmenter_train(&self, request: SegmenterTrainRequest) -> Result<serde_json::Value, BridgeError> {
        let r = request;
        self.call_json("cnfmp.segmenter.api", "train", move |py| {
            Ok(kwargs!(py, out_dir = r.out, config_path = r.config, steps = r.steps, seed = r.seed,
                       scenes_scale = r.scenes_scale, command = r.command))
        })
    }

    /// Evaluates a backend on held-out renders (`cnfmp.segmenter.api.evaluate`); progress on
    /// stderr. Returns the report JSON (mean IoU per split, rejection rate, latency, per scene).
    pub fn segmenter_eval(
        &self,
        task: &str,
        episodes: u64,
        seed_start: u64,
        backend: &str,
        weights: Option<PathBuf>,
    ) -> Result<serde_json::Value, BridgeError> {
        let (task, backend) = (task.to_owned(), backend.to_owned());
        self.call_json("cnfmp.segmenter.api", "evaluate", move |py| {
            Ok(kwargs!(py, task = task, episodes = episodes, seed_start = seed_start, backend_name = backend, weights = weights))
        })
    }
}
