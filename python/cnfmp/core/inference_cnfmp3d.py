"""Prediction with a cnfmp-3d model: a new scan -> each object's latent -> the trajectory.

As in 2D, each object's latent is a point on its simplex, found by a search and a
refinement: candidates (every training demonstration's weights, the simplex vertices,
random points) are scored on samples near the object's scan points, carved against the
scan, by the object's expert against the background (occupancy BCE) plus the mask logits
against the coarse labels; the best few are refined by Adam on their simplex logits.
The templates depend on neither latent nor scene, so they are baked on a grid once at load
time; the background is evaluated at each object's fit samples. With helper processes
running (:mod:`cnfmp.helper_processes`), the objects are fitted side by side, each process
taking the next object when it is free.
"""

from __future__ import annotations

import dataclasses
import itertools
import os
import threading
import time
from dataclasses import dataclass

import numpy as np
import torch
from torch.nn import functional as F

from cnfmp import helper_processes
from cnfmp.scan import Scan
from cnfmp.core import occupancy
from cnfmp.core.adam import Adam
from cnfmp.core.modeling_cnfmp3d import BakedTemplate, Cnfmp3dModel
from cnfmp.core.motion import decode_trajectory, output_times
from cnfmp.errors import InputError


@dataclass
class FittedScan:
    """The latent fit of one scan (N objects, K endpoints, D latent size).

    Attributes:
        weights: (N, K) simplex weights; latents: (N, D).
        centres: (N, 3) object centres (box coordinates); turns: (N,) rad about the vertical.
        anchors: (N, 3) centroids of the objects' scan points (box coordinates).
        losses: per object, the fit's loss (occupancy BCE + weighted mask BCE) at the end.
        points: the scan's fused points inside the box.
    """

    weights: torch.Tensor
    latents: torch.Tensor
    centres: torch.Tensor
    turns: torch.Tensor
    anchors: torch.Tensor
    losses: list[float]
    points: occupancy.ScanPoints


@dataclass
class HelperFit3d:
    """A message to a helper process (:func:`fit_in_helper`): fit object `job` (the
    arguments of :meth:`Predictor3d._object_job`) with the predictor called `key`, first
    building it from `model` (config, {state-dict name: numpy array}) when the helper has
    not got it."""

    key: str
    model: tuple | None
    job: tuple


HELPER_HANDLER = "cnfmp.core.inference_cnfmp3d:fit_in_helper"
_HELPER_PREDICTORS: dict[str, "Predictor3d"] = {}
_KEYS = itertools.count()


def fit_in_helper(message: HelperFit3d) -> tuple:
    """Runs in a helper process: one object's fit, as :meth:`Predictor3d._object_job`
    returns it with the weights as a numpy array."""
    if message.model is not None:
        config, state = message.model
        tensors = {name: torch.from_numpy(array) for name, array in state.items()}
        model = Cnfmp3dModel.from_state(config, tensors)
        model.load_state_dict(tensors)
        _HELPER_PREDICTORS[message.key] = Predictor3d(model)
    predictor = _HELPER_PREDICTORS.get(message.key)
    if predictor is None:
        raise helper_processes.HelperError(f"helper process {os.getpid()} holds no predictor {message.key}")
    weights, loss = predictor._object_job(*message.job)
    return weights.numpy(), loss


class Predictor3d:
    """A trained cnfmp-3d model ready to predict: parameters frozen, templates baked."""

    def __init__(self, model: Cnfmp3dModel):
        self.model, self.config = model, model.config
        model.eval()
        for p in model.parameters():
            p.requires_grad_(False)
        self.box = occupancy.SceneBox.of(self.config)
        spacing = self.config.bake_spacing_m / self.config.box_half
        self.baked = [BakedTemplate(field, torch.tensor(b[:3]), torch.tensor(b[3:]), spacing)
                      for field, b in zip(model.objects, self.config.template_boxes)] if self.config.template_boxes else None
        with torch.no_grad():
            self.demo_weights = torch.softmax(model.demo_logits, dim=-1)  # (B_train, N, K)
        self._helper_key = f"{os.getpid()}-3d-{next(_KEYS)}"
        self._sent_to: set[int] = set()  # pids of the helpers holding a copy
        self._helper_lock = threading.Lock()

    def _template(self, slot: int):
        return None if self.baked is None else self.baked[slot]

    def object_loss(self, slot: int, weights: torch.Tensor, samples: dict, count: int, anchor: torch.Tensor) -> torch.Tensor:
        """The fit's loss of candidates `weights` (C, K) on the first `count` samples of
        object `slot`: (C,)."""
        c = self.config
        model = self.model
        points = samples["points"][:count]
        latent = model.object_latent(slot, weights)
        occ, mask = model.objects[slot](points[None].expand(len(weights), -1, -1), latent,
                                        anchor[None].expand(len(weights), -1), self._template(slot))
        terms = torch.stack([occ, mask], dim=-1)
        occupancy_p = model.expert_occupancy(terms, samples["background"][None, :count])
        known = samples["known"][:count]
        occupancy_loss = (F.binary_cross_entropy(occupancy_p.clamp(1e-5, 1 - 1e-5),
                                                 samples["occupied"][None, :count].expand_as(occupancy_p),
                                                 reduction="none") * known).sum(dim=1) / known.sum().clamp(min=1.0)
        ownership = mask - samples["background"][None, :count, 1]
        mask_loss = F.binary_cross_entropy_with_logits(ownership, samples["mine"][None, :count].expand_as(ownership),
                                                       reduction="none").mean(dim=1)
        return occupancy_loss + c.mask_prior_weight * mask_loss

    def fit_scan(self, scan, seed: int = 0) -> FittedScan:
        """Each object's latent for `scan` (a :class:`cnfmp.scan.Scan`). InputError when an
        object slot has no scan points inside the scene box."""
        c, model = self.config, self.model
        points = occupancy.scan_points(scan, self.box, c.num_objects, tuple(scan.objects) or tuple(c.object_names))
        anchors = torch.from_numpy(points.anchors(self.box, c.num_objects))
        # Numpy, not tensors, in the jobs, and only what the fit reads (no colour, the points
        # a sample can reach): they may travel to a helper process by pickle.
        depth_only = Scan(tuple(dataclasses.replace(view, rgb=None) for view in scan.views), scan.objects)
        reach = 3 * max(c.surface_jitter_m) + c.coarse_label_radius_m
        jobs = [(slot, depth_only, points.around_object(slot, reach), anchors[slot].numpy(), seed)
                for slot in range(c.num_objects)]
        helpers = helper_processes.helpers() if len(jobs) > 1 else []
        if helpers:
            fits = self._fit_on_helpers(jobs, helpers)
        else:
            fits = [self._object_job(*job) for job in jobs]
        weights, losses = [w for w, _ in fits], [loss for _, loss in fits]
        weights = torch.stack(weights)
        with torch.no_grad():
            latents = model.latents(weights[None])[0]
            centres, turns = model.poses(latents[None], anchors[None])
        return FittedScan(weights, latents, centres[0], turns[0], anchors, losses, points)

    def _object_job(self, slot: int, scan, points: occupancy.ScanPoints, anchor: np.ndarray,
                    seed: int) -> tuple[torch.Tensor, float]:
        """Object `slot`'s fit on `scan`: its samples near its scan points, carved and
        coarse-labelled, then the search and refinement; `anchor` (3,) its centroid (box
        coordinates). Returns (weights (K,), loss)."""
        c = self.config
        anchor = torch.from_numpy(anchor)
        rng = np.random.default_rng([seed, slot])
        world = occupancy.near_surface(points.of_object(slot), c.fit_samples, c.surface_jitter_m, rng)
        labelled = occupancy.label_samples(world, scan, points, self.box, c)
        coords = torch.from_numpy(labelled.points)
        with torch.no_grad():
            background = self.model.background_terms(coords[None])[0]
        samples = {"points": coords, "occupied": torch.from_numpy(labelled.occupied),
                   "known": torch.from_numpy(labelled.known).float(), "background": background,
                   "mine": torch.from_numpy((labelled.coarse == slot).astype(np.float32))}
        return self._fit_object(slot, samples, anchor, rng)

    def _fit_on_helpers(self, jobs: list[tuple], helpers: list) -> list[tuple]:
        """The object jobs shared between this thread and the helper processes
        (:func:`cnfmp.helper_processes.share`)."""

        def there(helper, j: int) -> tuple:
            with self._helper_lock:  # the first message to a helper carries the model
                model = None
                if helper.process.pid not in self._sent_to:
                    model = (self.model.config, {name: value.numpy() for name, value in self.model.state_dict().items()})
                future = helper.submit(HELPER_HANDLER, HelperFit3d(self._helper_key, model, jobs[j]))
                self._sent_to.add(helper.process.pid)
            weights, loss = future.result()
            return torch.from_numpy(weights), loss

        return helper_processes.share(len(jobs), lambda j: self._object_job(*jobs[j]), there, helpers)

    def _fit_object(self, slot: int, samples: dict, anchor: torch.Tensor, rng: np.random.Generator):
        c = self.config
        k = c.num_endpoints
        candidates = torch.cat([self.demo_weights[:, slot], torch.eye(k),
                                torch.from_numpy(rng.dirichlet(np.ones(k), c.search_candidates).astype(np.float32))])
        with torch.no_grad():
            scores = self.object_loss(slot, candidates, samples, c.search_samples, anchor)
        starts = candidates[torch.argsort(scores)[:c.search_starts]]
        logits = torch.log(starts.clamp(min=1e-3)).requires_grad_(True)
        optimiser = Adam(logits, lr=c.refine_learning_rate)
        for _ in range(c.refine_steps):
            loss = self.object_loss(slot, torch.softmax(logits, dim=-1), samples, c.refine_samples, anchor)
            optimiser.zero_grad()
            loss.sum().backward()
            optimiser.step()
        with torch.no_grad():
            final = torch.softmax(logits, dim=-1)
            scores = self.object_loss(slot, final, samples, c.refine_samples, anchor)
            best = int(torch.argmin(scores))
        return final[best].detach(), float(scores[best])

    def predict_scan(self, scan, seed: int = 0) -> dict:
        """The trajectory for `scan`: ``{"trajectory": decode_trajectory's dict, "fit":
        FittedScan, "seconds": {"infer", "decode"}}``."""
        started = time.perf_counter()
        fit = self.fit_scan(scan, seed)
        fitted = time.perf_counter()
        with torch.no_grad():
            t = torch.from_numpy(output_times(self.config).astype(np.float32))
            outputs = self.model.motion(t, fit.latents[None], fit.centres[None], fit.turns[None])[0].numpy()
        trajectory = decode_trajectory(outputs.astype(np.float64), self.config)
        return {"trajectory": trajectory, "fit": fit,
                "seconds": {"infer": fitted - started, "decode": time.perf_counter() - fitted}}

    def predict(self, image, labels, seed: int = 0):
        raise InputError(f"the model ({self.config.task}) is a cnfmp-3d model: it predicts from a scan "
                         "(`cnfmp predict --scan DIR`), not from one image")


__all__ = ["FittedScan", "Predictor3d"]
