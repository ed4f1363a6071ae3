//! robomimic-style HDF5 files as a conversion source. h5py (in `cnfmp.data.hdf5`) reads the
//! arrays of one demo; everything after that (trajectory validation, PNG encoding) runs in
//! the conversion's Rust workers.

use std::path::Path;

use segmenter_bridge::{Bridge, BridgeError, Hdf5Listing, TrajectoryArrays};
use segmenter_bridge::ndarray::{Array1, Axis};
use serde_json::Map;

use super::episode::{BadEpisode, EpisodeError, SourceEpisode};
use crate::images::Image;
use crate::trajectory::Trajectory;

/// Reads demo `demo` of `file` (listed in `listing`, which gives its rate and camera) through the bridge.
pub fn read_episode(bridge: &Bridge, file: &Path, demo: &str, listing: &Hdf5Listing) -> Result<SourceEpisode, EpisodeError> {
    let bad = |reason: String| EpisodeError::Bad(BadEpisode { episode: demo.to_owned(), file: format!("{}:data/{demo}", file.display()), reason });
    let data = match bridge.hdf5_demo(file, demo, listing.camera.clone()) {
        Ok(data) => data,
        Err(BridgeError::InvalidInput(reason)) => return Err(bad(reason)),
        Err(other) => return Err(EpisodeError::Fatal(other.into())),
    };
    let count = data.position.nrows();
    let arrays = TrajectoryArrays {
        fps: listing.fps,
        t: Array1::from_iter((0..count).map(|k| k as f64 / listing.fps)),
        position: data.position,
        orientation: data.orientation,
        gripper: data.gripper,
    };
    let trajectory = Trajectory::from_arrays(&arrays, Map::new()).map_err(|err| bad(format!("robot0_eef_* / gripper_qpos {err}")))?;
    let (height, width) = (data.images.shape()[1] as u32, data.images.shape()[2] as u32);
    let images = data
        .images
        .axis_iter(Axis(0))
        .map(|frame| Image { width, height, channels: 3, pixels: frame.iter().copied().collect() })
        .collect();
    let masks = Image { width, height, channels: 1, pixels: data.masks.iter().copied().collect() };
    Ok(SourceEpisode {
        name: demo.to_owned(),
        source: format!("{}:data/{demo}", file.display()),
        prompt: data.prompt,
        task: String::new(),
        seed: None,
        trajectory,
        images,
        masks,
        objects: data.objects,
    })
}
