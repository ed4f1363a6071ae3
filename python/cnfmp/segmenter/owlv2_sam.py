"""OWLv2 + SAM segmenter backend: open-vocabulary boxes from OWLv2, refined into masks by SAM.

OWLv2 scores every image patch's box against all phrases in one forward pass; each phrase
keeps its best box, which prompts SAM. SAM's image embedding is computed once per image and
shared by every phrase's box. A phrase's probability map is SAM's mask probability times the
OWLv2 box score, so a weak detection yields a weak map and the shared post-processing reports
the phrase as not found. Weights come from two local directories (owlv2/ and sam/ layouts of
google/owlv2-base-patch16-ensemble and facebook/sam-vit-base); ~40 s per prompt on a CPU.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from cnfmp.segmenter.base import Backend, check_image
from cnfmp.segmenter.clipseg import load_local_model, load_local_processor, pick_device
from cnfmp.segmenter.postprocess import PostprocessConfig


class Owlv2SamBackend(Backend):
    """OWLv2 detection + SAM box-prompted masks, both loaded from local directories."""

    name = "owlv2-sam"
    open_vocabulary = True
    grounds_categories = True
    # Probabilities are scaled by OWLv2 sigmoid scores, which sit around 0.2-0.7 for clearly
    # visible objects and below ~0.1 for absent ones (0.1 is OWLv2's usual detection cut-off).
    postprocess = PostprocessConfig(threshold=0.1, min_score=0.15)

    def __init__(self, owlv2_dir: Path, sam_dir: Path, device: str | torch.device | None = None):
        from transformers import Owlv2ForObjectDetection, Owlv2Processor, SamModel, SamProcessor

        self.owlv2_dir, self.sam_dir = Path(owlv2_dir), Path(sam_dir)
        self.device = pick_device(device)
        self.detector = load_local_model(Owlv2ForObjectDetection, self.owlv2_dir, "owlv2", "OWLv2").to(self.device)
        self.detector_processor = load_local_processor(Owlv2Processor, self.owlv2_dir, "OWLv2")
        self.sam = load_local_model(SamModel, self.sam_dir, "sam", "SAM").to(self.device)
        self.sam_processor = load_local_processor(SamProcessor, self.sam_dir, "SAM")
        self.max_text_tokens = int(self.detector.config.text_config.max_position_embeddings)

    def describe(self) -> dict:
        return {"backend": self.name, "owlv2": str(self.owlv2_dir), "sam": str(self.sam_dir), "device": str(self.device)}

    def detect(self, image: np.ndarray, phrases: list[str]) -> tuple[np.ndarray, np.ndarray]:
        """(H, W, 3) uint8 RGB and P phrases -> each phrase's best OWLv2 box as (P, 4) float32
        [x0, y0, x1, y1] image pixels, and its (P,) sigmoid score in [0, 1]."""
        height, width = image.shape[:2]
        pixels = self.detector_processor.image_processor(images=image, return_tensors="pt")["pixel_values"]
        # OWLv2 queries must be exactly max_position_embeddings tokens long (16 for the base model).
        text = self.detector_processor.tokenizer(
            list(phrases), padding="max_length", truncation=True, max_length=self.max_text_tokens, return_tensors="pt"
        )
        with torch.inference_mode():
            output = self.detector(
                input_ids=text["input_ids"].to(self.device),
                attention_mask=text["attention_mask"].to(self.device),
                pixel_values=pixels.to(self.device),
            )
            scores = output.logits[0].float().sigmoid()  # (patches, P)
            best_scores, best_patches = scores.max(dim=0)  # (P,)
            cx, cy, w, h = output.pred_boxes[0, best_patches].float().unbind(-1)  # each (P,), in [0, 1]
        # Boxes are relative to the square the processor pads the image into (bottom/right).
        side = max(height, width)
        boxes = torch.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], dim=-1).cpu().numpy() * side
        boxes = boxes.clip(0.0, [width, height, width, height]).astype(np.float32)
        return boxes, best_scores.cpu().numpy().astype(np.float32)

    def segment_boxes(self, image: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 RGB and (P, 4) [x0, y0, x1, y1] pixel boxes -> (P, H, W) float32 SAM
        mask probabilities: of the three multimask outputs, the one with the best predicted IoU."""
        height, width = image.shape[:2]
        image_processor = self.sam_processor.image_processor
        inputs = image_processor(images=image, return_tensors="pt")
        new_height, new_width = (int(v) for v in inputs["reshaped_input_sizes"][0])
        # Box prompts live in the resized (longest edge = SAM input size) image's pixels.
        scale = np.array([new_width / width, new_height / height] * 2, np.float32)
        prompts = torch.from_numpy(boxes * scale)[None].to(self.device)  # (1, P, 4)
        with torch.inference_mode():
            embeddings = self.sam.get_image_embeddings(inputs["pixel_values"].to(self.device))  # once for all boxes
            output = self.sam(image_embeddings=embeddings, input_boxes=prompts, multimask_output=True)
            # pred_masks (1, P, 3, h, w) low-resolution logits; iou_scores (1, P, 3).
            best = output.iou_scores[0].argmax(dim=-1)
            logits = output.pred_masks[0, torch.arange(len(boxes), device=best.device), best].float()  # (P, h, w)
            logits = image_processor.post_process_masks(
                [logits[:, None]], inputs["original_sizes"], inputs["reshaped_input_sizes"], binarize=False
            )[0]  # (P, 1, H, W), padding removed
            return logits[:, 0].sigmoid().cpu().numpy()

    def probabilities(self, image: np.ndarray, phrases: list[str]) -> np.ndarray:
        """(H, W, 3) uint8 RGB and P phrases -> (P, H, W) float32 in [0, 1]: SAM's mask
        probability inside each phrase's best OWLv2 box, times that box's score."""
        image = check_image(image)
        height, width = image.shape[:2]
        if not phrases:
            return np.zeros((0, height, width), np.float32)
        boxes, scores = self.detect(image, phrases)
        masks = self.segment_boxes(image, boxes)
        return (masks * scores[:, None, None]).clip(0.0, 1.0).astype(np.float32, copy=False)


__all__ = ["Owlv2SamBackend"]
