//! Which segmenter grounds a prompt: the `--backend`/`--weights` flags that `segment`,
//! `predict`, `eval` and `serve` share, the call that runs it, and a one-line-per-phrase
//! description of its answer.

use std::path::{Path, PathBuf};

use clap::Args;
use segmenter_bridge::{Bridge, SegmentRequest, Segmentation};

use crate::failure::Failure;

/// Which segmenter grounds the prompt.
#[derive(Debug, Clone, Args)]
pub struct BackendArgs {
    /// auto (film if its checkpoint loads, else clipseg if $CNFMP_CLIPSEG_DIR is set, else
    /// color), film, clipseg, owlv2-sam (slow on CPU) or color (HSV heuristic, no weights).
    // Python checks the name: cnfmp.segmenter.backends holds the one list.
    #[arg(long, default_value = "auto")]
    pub backend: String,
    /// Weights directory of the backend (film: models/segmenter; clipseg: a CIDAS/clipseg-rd64-refined
    /// download; owlv2-sam: a directory holding owlv2/ and sam/). Never downloaded.
    #[arg(long)]
    pub weights: Option<PathBuf>,
}

/// Segments `image` for `prompt`; with `roles`, the label map is ordered for a model whose
/// slots take those prompt roles; with `pictures`, the per-phrase masks and the overlay are
/// encoded too.
pub fn run_segmenter(
    bridge: &Bridge,
    image: Vec<u8>,
    prompt: &str,
    backend: &BackendArgs,
    roles: Option<&[String]>,
    pictures: bool,
) -> Result<Segmentation, Failure> {
    Ok(bridge.segment(SegmentRequest {
        image,
        prompt: prompt.to_owned(),
        backend: backend.backend.clone(),
        weights: backend.weights.clone(),
        roles: roles.map(<[String]>::to_vec),
        pictures,
    })?)
}

/// The prompt role of each object slot of the model at `model` (`ModelDescription::roles`:
/// the vocabulary's task_roles, or those `cnfmp dataset annotate` recorded); BadInput when
/// prompts cannot drive it.
pub fn prompt_roles(bridge: &Bridge, model: &Path) -> Result<Vec<String>, Failure> {
    let description = bridge.core_describe(model)?;
    description.roles.ok_or_else(|| {
        Failure::BadInput(format!(
            "prompts cannot drive the {} model at {}: its objects have no prompt roles (neither task_roles in \
             prompts/vocabulary.json nor an annotation by `cnfmp dataset annotate` gives them); pass coarse masks instead",
            description.task,
            model.display()
        ))
    })
}

/// One line per phrase: what was found, where, how sure.
pub fn describe(segmentation: &Segmentation) -> String {
    segmentation
        .document
        .objects
        .iter()
        .map(|o| match (o.found, o.bbox) {
            (true, Some([x0, y0, x1, y1])) => {
                format!("  {}: {:?} ({}) found, score {:.2}, {} px, box [{x0}, {y0}, {x1}, {y1})", o.label, o.phrase, o.role, o.score, o.area)
            }
            _ => format!("  {}: {:?} ({}) NOT FOUND (best score {:.2})", o.label, o.phrase, o.role, o.score),
        })
        .collect::<Vec<_>>()
        .join("\n")
}
