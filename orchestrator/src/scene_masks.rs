//! Coarse masks given with a scene instead of a prompt: a label map (0 background, k the k-th
//! object) and the object names in label order. `cnfmp predict --masks` and the HTTP API read
//! them through this one module, so both accept the same inputs and refuse the same mistakes
//! with the same codes, before any Python work starts.

use serde_json::Value;

use crate::images::{self, Image};

/// Why given masks cannot be used: a stable code (the HTTP API's error code) and a message
/// that says what to fix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MaskError {
    pub code: &'static str,
    pub message: String,
}

impl MaskError {
    fn new(code: &'static str, message: impl Into<String>) -> Self {
        MaskError { code, message: message.into() }
    }
}

impl std::fmt::Display for MaskError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.message)
    }
}

/// Object names from JSON: `["a", "b"]`, or an object with an `"objects"` list (the
/// objects.json that `cnfmp sim render` and `cnfmp segment` write). Names must be non-empty
/// and distinct.
pub fn parse_objects(value: &Value) -> Result<Vec<String>, MaskError> {
    let list = value.get("objects").unwrap_or(value);
    let names: Vec<String> = serde_json::from_value(list.clone()).map_err(|_| {
        MaskError::new("invalid_objects", "the objects must be a JSON list of names, or {\"objects\": [names]}")
    })?;
    check_names(names)
}

/// `names` when they can name a label map's objects: at least one, each non-empty, no two alike.
pub fn check_names(names: Vec<String>) -> Result<Vec<String>, MaskError> {
    if names.is_empty() {
        return Err(MaskError::new("invalid_objects", "the objects list is empty; name every labelled object in label order"));
    }
    for (k, name) in names.iter().enumerate() {
        if name.trim().is_empty() {
            return Err(MaskError::new("invalid_objects", format!("object {} has an empty name", k + 1)));
        }
        if names[..k].contains(name) {
            return Err(MaskError::new("invalid_objects", format!("object `{name}` is named twice")));
        }
    }
    Ok(names)
}

/// Object names from JSON text (see [`parse_objects`]).
pub fn parse_objects_text(text: &[u8]) -> Result<Vec<String>, MaskError> {
    let value: Value = serde_json::from_slice(text)
        .map_err(|err| MaskError::new("invalid_objects", format!("the objects are not valid JSON: {err}")))?;
    parse_objects(&value)
}

/// A checked label map and the names of its labels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CoarseMasks {
    /// One channel, the image's size.
    pub labels: Image,
    /// Names in label order: label k is `objects[k - 1]`.
    pub objects: Vec<String>,
}

impl CoarseMasks {
    /// Decodes and checks a label-map PNG against the scene image's size (width, height in
    /// px) and the names: every label used must be named.
    pub fn from_png(png: &[u8], objects: Vec<String>, image_size: (u32, u32)) -> Result<Self, MaskError> {
        let labels = images::label_map_from_png(png)
            .map_err(|reason| MaskError::new("invalid_masks", format!("the masks are not a label map PNG: {reason}")))?;
        if (labels.width, labels.height) != image_size {
            return Err(MaskError::new(
                "masks_size_mismatch",
                format!("the masks are {} but the image is {}x{}; they must have the same size", labels.size(), image_size.0, image_size.1),
            ));
        }
        let highest = labels.max_label() as usize;
        if highest > objects.len() {
            return Err(MaskError::new(
                "unnamed_label",
                format!(
                    "the masks use label {highest} but the objects name {} object(s); name every labelled object, in label order",
                    objects.len()
                ),
            ));
        }
        Ok(CoarseMasks { labels, objects })
    }

    /// Refuses more objects than a model has slots (`slot_names`, in slot order).
    pub fn check_slots(&self, slot_names: &[String]) -> Result<(), MaskError> {
        if self.objects.len() > slot_names.len() {
            return Err(MaskError::new(
                "too_many_objects",
                format!(
                    "{} objects given but the model has {} object slot(s): {}; label only those objects, in that order",
                    self.objects.len(),
                    slot_names.len(),
                    slot_names.join(", ")
                ),
            ));
        }
        Ok(())
    }

    /// The label map as an 8-bit grayscale PNG, what the core reads.
    pub fn png(&self) -> Vec<u8> {
        images::png_bytes(&self.labels)
    }

    /// Area (px), bounding box [x0, y0, x1) and centroid [x, y] (px) of label `label`, or
    /// None when no pixel carries it.
    pub fn region(&self, label: u8) -> Option<Region> {
        let width = self.labels.width as usize;
        let (mut area, mut sum_x, mut sum_y) = (0u64, 0f64, 0f64);
        let mut bbox = [u32::MAX, u32::MAX, 0, 0];
        for (index, _) in self.labels.pixels.iter().enumerate().filter(|(_, value)| **value == label) {
            let (x, y) = ((index % width) as u32, (index / width) as u32);
            area += 1;
            sum_x += x as f64;
            sum_y += y as f64;
            bbox = [bbox[0].min(x), bbox[1].min(y), bbox[2].max(x + 1), bbox[3].max(y + 1)];
        }
        (area > 0).then(|| Region { area, bbox, centroid: [sum_x / area as f64, sum_y / area as f64] })
    }
}

/// Where one object's coarse mask lies in the image (px).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    pub area: u64,
    /// [x0, y0, x1, y1), exclusive upper corner.
    pub bbox: [u32; 4],
    pub centroid: [f64; 2],
}

/// The size (width, height in px) an encoded image declares in its header, without decoding.
pub fn image_size(image: &[u8]) -> Option<(u32, u32)> {
    imagesize::blob_size(image).ok().map(|size| (size.width as u32, size.height as u32))
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    fn labels(width: u32, height: u32, pixels: Vec<u8>) -> Vec<u8> {
        images::png_bytes(&Image { width, height, channels: 1, pixels })
    }

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|name| name.to_string()).collect()
    }

    #[test]
    fn objects_come_as_a_list_or_an_objects_document() {
        assert_eq!(parse_objects(&json!(["block", "tray"])).unwrap(), names(&["block", "tray"]));
        assert_eq!(parse_objects(&json!({"objects": ["block"], "task": "x"})).unwrap(), names(&["block"]));
        assert_eq!(parse_objects_text(b"[\"a\"]").unwrap(), names(&["a"]));
        for bad in [json!([]), json!(["a", "a"]), json!([" "]), json!([1]), json!({"names": ["a"]})] {
            assert_eq!(parse_objects(&bad).unwrap_err().code, "invalid_objects", "{bad}");
        }
        assert_eq!(parse_objects_text(b"[\"a\"").unwrap_err().code, "invalid_objects");
    }

    #[test]
    fn masks_are_checked_against_the_image_and_the_names() {
        let png = labels(3, 2, vec![0, 1, 1, 0, 2, 0]);
        let masks = CoarseMasks::from_png(&png, names(&["block", "tray"]), (3, 2)).unwrap();
        assert_eq!(masks.labels.max_label(), 2);
        assert_eq!(CoarseMasks::from_png(&masks.png(), names(&["block", "tray"]), (3, 2)).unwrap(), masks);
        let error = |png: &[u8], objects: &[&str], size| CoarseMasks::from_png(png, names(objects), size).unwrap_err().code;
        assert_eq!(error(&png, &["block", "tray"], (4, 2)), "masks_size_mismatch");
        assert_eq!(error(&png, &["block"], (3, 2)), "unnamed_label");
        assert_eq!(error(b"GIF89a....", &["block"], (3, 2)), "invalid_masks");
        assert_eq!(error(&png[..png.len() / 2], &["block", "tray"], (3, 2)), "invalid_masks");
        let rgb = images::png_bytes(&Image { width: 1, height: 1, channels: 3, pixels: vec![1, 2, 3] });
        assert_eq!(error(&rgb, &["block"], (1, 1)), "invalid_masks");
        assert_eq!(masks.check_slots(&names(&["target"])).unwrap_err().code, "too_many_objects");
        assert!(masks.check_slots(&names(&["target", "destination", "obstacle"])).is_ok());
    }

    #[test]
    fn regions_give_area_box_and_centroid() {
        let masks = CoarseMasks::from_png(&labels(3, 2, vec![0, 1, 1, 0, 1, 0]), names(&["a", "b"]), (3, 2)).unwrap();
        let region = masks.region(1).unwrap();
        assert_eq!((region.area, region.bbox), (3, [1, 0, 3, 2]));
        assert_eq!(region.centroid, [4.0 / 3.0, 1.0 / 3.0]);
        assert!(masks.region(2).is_none());
    }
}
