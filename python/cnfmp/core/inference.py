"""Inference: a new scene image + coarse masks -> object latents -> trajectory.

The networks stay frozen. For each present object only its simplex weights are optimised,
against the reconstruction of its dilated masked region by its expert and the background:
a cheap search over candidates (every training demonstration's weights, the simplex vertices
and random points) picks the best few, which Adam refines in parallel (multi-start). The
refinement reads the object's appearance from a grid baked for the scene and interpolates its
low-frequency deformation residual from a coarse grid, rather than running both networks on
every pixel at every step (refinement 2-2.5x faster, fitting as well: docs/experiments.md,
"Faster latent fit: baked grids"); the search and the whole-image rendering of the scene fit
interpolate that residual too. The final reconstruction error of each object, with the
networks, is its confidence signal.

Where :mod:`cnfmp.helper_processes` runs helpers, a scene's (or batch's) object fits are
shared between this process and its helpers, which hold a copy of the predictor: the same
code on the same weights, so every answer is the same bit for bit wherever its objects ran.
"""

from __future__ import annotations

import itertools
import os
import sys
import threading
import time
import weakref
from dataclasses import dataclass

import numpy as np
import torch

from cnfmp import helper_processes, runtime
from cnfmp.core import data as core_data, segment_timing
from cnfmp.core.adam import Adam
from cnfmp.core.configuration_cnfmp import (CENTRE_PRIOR_WEIGHT, RESIDUAL_GRID_PIXELS, SEARCH_PIXELS, SIMPLEX_MARGIN,
                                             TEXELS_PER_PIXEL, WEIGHT_PRIOR_WEIGHT, CnfmpConfig)
from cnfmp.core.layers import pixel_coords
from cnfmp.core.modeling_cnfmp import BakedAppearance, CnfmpModel, CoarseResidual
from cnfmp.core.motion import decode_trajectory, output_times
from cnfmp.errors import InputError


#: How far (image coordinates in [-1, 1]; 0.1 is 3 px at 64 px) the baked appearance reaches
#: beyond the template coordinates of the refinement's starts.
BAKE_MARGIN = 0.1


@dataclass(frozen=True)
class FittedPixels:
    """What one object's fit compares: the pixels of its dilated mask that inference reads
    (in random order, so any first few are a random sample too), and at them the scene's
    image and the frozen background. P pixels; image coordinates in [-1, 1]."""

    #: (1, P, 2) the pixels' image coordinates.
    coords: torch.Tensor
    #: (1, 3) the object's observed colour (median under its coarse mask), in [0, 1].
    colour: torch.Tensor
    #: (1, P, 3) and (1, P): the background field's colour and mask logit at the pixels.
    bg_rgb: torch.Tensor
    bg_logit: torch.Tensor
    #: (1, P, 3) the scene's image at the pixels, in [0, 1].
    target: torch.Tensor
    #: (1, 2) the centroid of the object's coarse mask.
    centre: torch.Tensor

    def first(self, count: int) -> "FittedPixels":
        """The first `count` pixels alone (a random sample of them)."""
        few = slice(0, count)
        return FittedPixels(self.coords[:, few], self.colour, self.bg_rgb[:, few], self.bg_logit[:, few],
                            self.target[:, few], self.centre)


@dataclass(frozen=True)
class HelperFits:
    """A message to a helper process (:func:`fit_in_helper`): fit these objects with the
    predictor called `key`, first building it from `model` when the helper has not got it;
    with `fits` None, forget that predictor."""

    key: str
    #: (model config, inference settings, {state-dict name: numpy array}) or None.
    model: tuple | None
    #: Per object: the arguments of :meth:`Predictor._fit_object` (inputs, slot, draws, exact, render).
    fits: list[tuple] | None


#: The handler helper processes run for a :class:`Predictor`.
HELPER_HANDLER = "cnfmp.core.inference:fit_in_helper"

#: In a helper process: the predictors its parent sent, by key.
_HELPER_PREDICTORS: dict[str, "Predictor"] = {}

_KEYS = itertools.count()


def fit_in_helper(message: HelperFits) -> list[tuple] | None:
    """Runs in a helper process: the fits of `message`, each as :meth:`Predictor._fit_object`
    returns it with numpy arrays for tensors (see :func:`_as_arrays`)."""
    if message.fits is None:
        _HELPER_PREDICTORS.pop(message.key, None)
        return None
    if message.model is not None:
        config, settings, state = message.model
        tensors = {name: torch.from_numpy(array) for name, array in state.items()}
        model = CnfmpModel.from_state(config, tensors)
        model.load_state_dict(tensors)
        _HELPER_PREDICTORS[message.key] = Predictor(model, settings)
    predictor = _HELPER_PREDICTORS.get(message.key)
    if predictor is None:
        raise helper_processes.HelperError(f"helper process {os.getpid()} holds no predictor {message.key}")
    return [_as_arrays(predictor._fit_object(*fit)) for fit in message.fits]


def _as_arrays(value):
    """`value` with every tensor in it (nested in tuples) as a numpy array, for a pipe."""
    if isinstance(value, torch.Tensor):
        return value.numpy()
    if isinstance(value, tuple):
        return tuple(_as_arrays(v) for v in value)
    return value


def _as_tensors(value):
    """The inverse of :func:`_as_arrays`."""
    if isinstance(value, np.ndarray):
        return torch.from_numpy(value)
    if isinstance(value, tuple):
        return tuple(_as_tensors(v) for v in value)
    return value


def _forget_in_helpers(key: str, sent: set, lock: threading.Lock) -> None:
    """Tells every helper holding predictor `key` to drop it (when the predictor is collected)."""
    with lock:
        for helper in helper_processes.helpers():
            if helper.process.pid in sent:
                try:
                    helper.submit(HELPER_HANDLER, HelperFits(key, None, None))
                except helper_processes.HelperError:
                    pass  # closed meanwhile: it forgets everything
        sent.clear()


def psnr_db(mse: float) -> float:
    """Peak signal-to-noise ratio (dB) of an MSE on [0, 1] images."""
    return float(10.0 * np.log10(1.0 / max(mse, 1e-10)))


class Predictor:
    """A loaded model ready to predict; holds the pixel grid and the background, which do not
    depend on the scene."""

    def __init__(self, model: CnfmpModel, settings: CnfmpConfig | None = None):
        """`settings`: the model's config with other inference settings (the fields of its
        "inference" section) to predict with; None: the model's own."""
        self.model = model.eval()
        for p in model.parameters():  # frozen: inference optimises simplex weights only
            p.requires_grad_(False)
        self.config = settings or model.config
        self.coords = pixel_coords(self.config.field_resolution)
        with torch.no_grad():
            self.bg_rgb, self.bg_logit = model.background_terms(self.coords[None])
            self.times = torch.from_numpy(output_times(self.config)).float()
        timing = self.config.segment_timing
        self.segment_timing = segment_timing.SegmentTiming.from_dict(timing) if timing else None
        self.whole_image_residual = self._coarse_residual(self.coords[None])
        # What the helper processes know of this predictor (see _fit_on_helpers).
        self._helper_key = f"{os.getpid()}-{next(_KEYS)}"
        self._sent_to: set[int] = set()  # pids of the helpers holding a copy
        self._helper_lock = threading.Lock()
        weakref.finalize(self, _forget_in_helpers, self._helper_key, self._sent_to, self._helper_lock).atexit = False

    def weights_of(self, logits: torch.Tensor) -> torch.Tensor:
        """Search logits (..., K) -> weights on the endpoints, a point of the simplex enlarged
        by SIMPLEX_MARGIN m: ``(1 + m) softmax(logits) - m / K`` (sums to one)."""
        m, k = SIMPLEX_MARGIN, logits.shape[-1]
        return (1.0 + m) * torch.softmax(logits, dim=-1) - m / k

    def _object_loss(self, slot: int, logits: torch.Tensor, pixels: FittedPixels,
                     baked: BakedAppearance | None = None,
                     coarse: CoarseResidual | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-candidate objective (C,) of slot `slot` for search logits (C, K) on `pixels`:
        the expert image's MSE plus the weighted centre prior; also returns the MSE alone.
        With `baked`, the object's appearance is read from that grid instead of its network;
        with `coarse` (built for these pixels), its deformation residual is interpolated
        from that grid."""
        c = logits.shape[0]
        weights = self.weights_of(logits)
        latent = self.model.object_latent(slot, weights)
        anchor = pixels.centre.expand(c, -1)
        rgb, logit, _ = self.model.objects[slot](pixels.coords.expand(c, -1, -1), latent, pixels.colour.expand(c, -1),
                                                 baked=baked, coarse=coarse, anchor=anchor)
        image = self.model.expert_image(rgb, logit, pixels.bg_rgb, pixels.bg_logit)
        mse = ((image - pixels.target) ** 2).mean(dim=(1, 2))
        centre_err = ((self.model.objects[slot].object_centre(latent, anchor) - pixels.centre) ** 2).sum(dim=-1)
        return (mse + CENTRE_PRIOR_WEIGHT * centre_err + WEIGHT_PRIOR_WEIGHT * self.model.weight_spread(weights), mse)

    def _draw(self, pixels: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """The random draws of one object's search: up to `inference_pixels` of its mask's
        `pixels` (flat indices) in random order, and max(`search_pool`, `search_candidates`)
        random points of the simplex (C, K)."""
        c = self.config
        return rng.permutation(pixels)[: c.inference_pixels], rng.dirichlet(
            np.ones(c.num_endpoints), size=max(c.search_pool, c.search_candidates))

    def _search(self, slot: int, pixels: np.ndarray, random_points: np.ndarray, rgb: torch.Tensor,
                colour: torch.Tensor, centre: torch.Tensor, exact: bool = False) -> tuple[torch.Tensor, FittedPixels]:
        """The cheap search of slot `slot` (with the draws of :meth:`_draw`; the scene's image
        (R * R, 3), the object's colour (3,) and mask centroid (1, 2)): scores every candidate
        on a few of its mask's pixels, after a screen on fewer still (`search_screen_pixels`),
        with the deformation residual interpolated from a coarse grid unless `exact`, and
        returns the best `search_starts` logits (S, K) with the pixels the refinement fits."""
        c = self.config
        idx = torch.from_numpy(pixels)
        fitting = FittedPixels(self.coords[idx][None], colour[None], self.bg_rgb[:, idx], self.bg_logit[:, idx],
                               rgb[idx][None], centre)
        k, m = c.num_endpoints, SIMPLEX_MARGIN
        # Every training demonstration's weights and the endpoints themselves, mapped into the
        # search's enlarged simplex, then random points of the enlarged simplex.
        known = torch.cat([torch.softmax(self.model.demo_logits[:, slot], dim=-1), torch.eye(k)])
        candidates = torch.cat([
            torch.log((known + m / k) / (1.0 + m) + 1e-6),
            self._nearest_centres(slot, torch.log(torch.from_numpy(random_points).float() + 1e-4), centre),
        ])
        with torch.no_grad():
            if c.search_screen_pixels and candidates.shape[0] > max(c.search_screen_keep, c.search_starts):
                screen = fitting.first(min(c.search_screen_pixels, SEARCH_PIXELS))
                losses, _ = self._object_loss(slot, candidates, screen,
                                              coarse=None if exact else self._coarse_residual(screen.coords))
                candidates = candidates[torch.argsort(losses)[: max(c.search_screen_keep, c.search_starts)]]
            few = fitting.first(SEARCH_PIXELS)
            coarse = None if exact else self._coarse_residual(few.coords)
            losses, _ = self._object_loss(slot, candidates, few, coarse=coarse)
        return candidates[torch.argsort(losses)[: c.search_starts]].clone(), fitting

    def _coarse_residual(self, coords: torch.Tensor) -> CoarseResidual | None:
        """The deformation residual's grid over the pixels `coords` (1, P, 2), RESIDUAL_GRID_PIXELS
        field pixels apart; None (evaluate it at every pixel) where the grid would not have
        under half as many points as there are pixels (a few pixels spread over a long
        object's box): interpolating would then cost more than it saves."""
        grid = CoarseResidual(coords, RESIDUAL_GRID_PIXELS * 2.0 / self.config.field_resolution)
        return grid if 2 * grid.size < coords.shape[1] else None

    def _nearest_centres(self, slot: int, logits: torch.Tensor, centre: torch.Tensor) -> torch.Tensor:
        """The `search_candidates` of the search logits (P, K) whose latents put slot `slot`'s
        centre nearest the mask centroid `centre` (1, 2): the centre prior of the objective,
        which needs no pixels, as an amortised first guess before the image is read."""
        wanted = self.config.search_candidates
        if logits.shape[0] <= wanted:
            return logits
        with torch.no_grad():
            latent = self.model.object_latent(slot, self.weights_of(logits))
            anchor = centre.expand(logits.shape[0], -1)
            error = ((self.model.objects[slot].object_centre(latent, anchor) - centre) ** 2).sum(dim=-1)
        return logits[torch.argsort(error)[:wanted]]

    def _bake(self, slot: int, starts: torch.Tensor, fitting: FittedPixels) -> BakedAppearance:
        """Slot `slot`'s appearance for this scene's colour, baked over the box of template
        coordinates that its refinement starts (S, K) map the fitted pixels to, widened by
        BAKE_MARGIN for the way the refinement moves them, at TEXELS_PER_PIXEL texels per
        field pixel. (The template's own support is no bound: far from what training saw,
        the appearance network may still claim pixels.)"""
        field = self.model.objects[slot]
        s = starts.shape[0]
        with torch.no_grad():
            seen = field.canonical(fitting.coords.expand(s, -1, -1),
                                   self.model.object_latent(slot, self.weights_of(starts)),
                                   anchor=fitting.centre.expand(s, -1)).reshape(-1, 2)
        spacing = 2.0 / (self.config.field_resolution * TEXELS_PER_PIXEL)
        return BakedAppearance(field, fitting.colour[0], seen.min(dim=0).values - BAKE_MARGIN,
                               seen.max(dim=0).values + BAKE_MARGIN, spacing)

    def infer_scene(self, inputs: core_data.SceneInputs, seed: int = 0,
                    exact: bool = False) -> tuple[torch.Tensor, list[float | None]]:
        """Simplex weights (N, K) of every object of a scene (its :class:`cnfmp.core.data.SceneInputs`,
        from :func:`cnfmp.core.data.scene_inputs`) and each present object's reconstruction
        MSE (None for an absent slot).

        A cheap search per object, then Adam refines the object's best starts (multi-start)
        with its appearance baked for the scene (TEXELS_PER_PIXEL); both interpolate
        the deformation residual from a coarse grid (RESIDUAL_GRID_PIXELS) where that grid
        is much smaller than the fitted pixels. `exact` evaluates the networks at every step
        instead. The MSE and the choice among the refined starts always use the networks."""
        return self.infer_scenes([inputs], [seed], exact)[0]

    def infer_scenes(self, scenes: list[core_data.SceneInputs], seeds: list[int],
                     exact: bool = False) -> list[tuple[torch.Tensor, list[float | None]]]:
        """:meth:`infer_scene` for several scenes at once, each with its own seed: every
        present object of every scene is one fit, and the fits run together on the worker
        pool (:func:`cnfmp.runtime.worker_pool`), so a batch keeps every core busy where one scene's few objects would not. Each
        scene's result is the same as :meth:`infer_scene` gives it alone."""
        return [(weights, mse) for weights, mse, _ in self._fit_scenes(scenes, seeds, exact, render=False)]

    def _fit_scenes(self, scenes: list[core_data.SceneInputs], seeds: list[int], exact: bool,
                    render: bool) -> list[tuple[torch.Tensor, list[float | None], dict[int, tuple]]]:
        """:meth:`infer_scenes`, plus per scene the whole-image rendering of each fitted object
        (slot -> what its field returns at every field pixel) when `render`: a fit's thread
        renders its object for the scene fit too, so a scene's objects render side by side
        with no second round on the pool."""
        c = self.config
        fits = []
        for index, (inputs, seed) in enumerate(zip(scenes, seeds)):
            rng = np.random.default_rng(seed)
            # Random draws in slot order (reproducible whatever runs in parallel below).
            fits += [(index, slot, self._draw(np.flatnonzero(inputs.dilated[slot].reshape(-1)), rng))
                     for slot in range(c.num_objects) if inputs.present[slot]]
        results = [(torch.full((c.num_objects, c.num_endpoints), 1.0 / c.num_endpoints), [None] * c.num_objects, {})
                   for _ in scenes]
        # The objects' objectives share nothing (Adam is per parameter), so they can be fitted
        # side by side: on helper processes where they run, else each on its own thread
        # (torch releases the GIL inside its kernels, but the kernels are small, so threads
        # wait on each other for the interpreter between them: two objects 1.2x, not 2x).
        jobs = [(scenes[index], slot, draws, exact, render) for index, slot, draws in fits]
        helpers = helper_processes.helpers()
        if helpers and len(jobs) > 1:
            fitted = self._fit_on_helpers(jobs, helpers)
        else:
            fitted = runtime.worker_pool().map(lambda job: self._fit_object(*job), jobs)
        for (index, slot, _), (slot_weights, slot_mse, rendered) in zip(fits, fitted):
            results[index][0][slot], results[index][1][slot] = slot_weights, slot_mse
            if rendered is not None:
                results[index][2][slot] = rendered
        return results

    def _fit_on_helpers(self, jobs: list[tuple], helpers: list[helper_processes.HelperProcess]) -> list[tuple]:
        """The fits `jobs` (arguments of :meth:`_fit_object`) shared between this thread and
        the helper processes, each taking the next unfitted object when it is free
        (:func:`cnfmp.helper_processes.share`: fits cost 20-50 ms, a round trip 1-2 ms). A
        helper keeps the copy of this predictor it got first, settings included: change
        settings by making a new Predictor, not in place."""

        def there(helper: helper_processes.HelperProcess, j: int) -> tuple:
            with self._helper_lock:  # the first message to a helper carries the model
                model = None
                if helper.process.pid not in self._sent_to:
                    model = (self.model.config, self.config,
                             {name: value.numpy() for name, value in self.model.state_dict().items()})
                future = helper.submit(HELPER_HANDLER, HelperFits(self._helper_key, model, [jobs[j]]))
                self._sent_to.add(helper.process.pid)
            return _as_tensors(future.result()[0])

        return helper_processes.share(len(jobs), lambda j: self._fit_object(*jobs[j]), there, helpers)

    def _fit_object(self, inputs: core_data.SceneInputs, slot: int, draws: tuple[np.ndarray, np.ndarray],
                    exact: bool, render: bool = False) -> tuple[torch.Tensor, float, tuple | None]:
        """The search and refinement of one present object (slot `slot` of the scene `inputs`,
        with its draws of :meth:`_draw`): its simplex weights (K,), reconstruction MSE and,
        with `render`, what its field returns at every field pixel for those weights (else None)."""
        c = self.config
        rgb = torch.from_numpy(inputs.rgb.reshape(-1, 3))
        colour, centre = torch.from_numpy(inputs.colour[slot]), torch.from_numpy(inputs.centre[slot])
        start, fitting = self._search(slot, *draws, rgb, colour, centre, exact)
        fast = c.refine_steps > 0 and not exact
        baked = self._bake(slot, start, fitting) if fast else None
        coarse = self._coarse_residual(fitting.coords) if fast else None
        searched = start.detach().clone()
        lowest = torch.full((start.shape[0],), float("inf"))
        best_seen = searched.clone()
        start.requires_grad_(True)
        optimiser = Adam(start, lr=c.refine_learning_rate)
        for _ in range(c.refine_steps):
            per_start = self._object_loss(slot, start, fitting, baked=baked, coarse=coarse)[0]
            with torch.no_grad():  # the loss is of the iterate before this step
                better = per_start < lowest
                lowest = torch.where(better, per_start, lowest)
                best_seen[better] = start[better]
            optimiser.zero_grad()
            per_start.sum().backward()
            optimiser.step()
        # Adam's first steps have the size of the learning rate whatever the gradient, so
        # from a start already near the optimum (a training scene's own weights) a short
        # refinement can end worse than it began. The choice is therefore made, with the
        # networks, among the search's starts, each start's best iterate (by the
        # refinement's own loss) and its last one: the fit never ends worse than its search.
        with torch.no_grad():
            candidates = torch.cat([searched, best_seen, start.detach()])
            final, errors = self._object_loss(slot, candidates, fitting)
            best = int(torch.argmin(final))
            weights = self.weights_of(candidates[best])
            rendered = (self.model.objects[slot](self.coords[None], self.model.object_latent(slot, weights[None]),
                                                 colour[None], anchor=centre.expand(1, -1),
                                                 coarse=self.whole_image_residual) if render else None)
            return weights, float(errors[best]), rendered

    def prepare(self, image: np.ndarray, labels: np.ndarray) -> core_data.SceneInputs:
        """A scene's inputs for :meth:`predict_prepared`: image (H, W, 3) uint8 and labels
        (H, W) uint8 in the model's slot order. InputError for masks this model cannot read."""
        c = self.config
        inputs = core_data.scene_inputs(image, labels, c.num_objects, c.field_resolution, c.mask_dilation)
        for slot in range(c.num_objects):
            if not inputs.present[slot] and not c.slot_can_be_absent[slot]:
                raise InputError(f"the masks have no pixels of object {slot + 1} ({c.object_names[slot]}), "
                                 "which every training scene of this model had")
        return inputs

    def predict(self, image: np.ndarray, labels: np.ndarray, seed: int = 0) -> dict:
        """Trajectory for a scene.

        Args:
            image: (H, W, 3) uint8; labels: (H, W) uint8 label map in the model's slot order.

        Returns ``{"trajectory": decode_trajectory dict, "weights": (N, K) simplex weights,
        "present": (N,) bool, "object_mse": per slot reconstruction MSE (None when absent),
        "object_psnr_db", "scene_psnr_db", "mask_iou": per slot IoU of the learned mask with the
        coarse mask, "reconstruction", "learned_masks", "seconds": {"infer", "decode"}}``.
        """
        return self.predict_prepared([self.prepare(image, labels)], [seed])[0]

    def predict_prepared(self, scenes: list[core_data.SceneInputs], seeds: list[int]) -> list[dict]:
        """:meth:`predict` for several prepared scenes (:meth:`prepare`) at once, their
        objects fitted together (:meth:`infer_scenes`); each result is what :meth:`predict`
        gives for that scene and seed alone, except "seconds"'s "infer", the whole batch's fit."""
        started = time.perf_counter()
        inferred = self._fit_scenes(scenes, seeds, exact=False, render=True)
        infer_s = time.perf_counter() - started
        if len(scenes) == 1:  # one scene: its objects' scene fits share the pool
            return [self._finish(scenes[0], *inferred[0], infer_s, runtime.worker_pool().map)]
        # Several: each scene is finished on a pool thread, its objects one after another.
        return list(runtime.worker_pool().map(lambda k: self._finish(scenes[k], *inferred[k], infer_s, map),
                                        range(len(scenes))))

    def _finish(self, inputs: core_data.SceneInputs, weights: torch.Tensor, mse: list[float | None],
                rendered: dict[int, tuple], infer_s: float, map_objects) -> dict:
        """The result of :meth:`predict` for a scene whose objects are fitted (weights (N, K),
        per-slot MSE, the fitted objects' renderings of :meth:`_fit_scenes`): its trajectory
        and the scene fit's confidences, any other slot rendered with `map_objects`."""
        decoding = time.perf_counter()
        present = torch.from_numpy(inputs.present)
        with torch.no_grad():
            latents = self.model.latents(weights[None], present[None])
            observations = torch.from_numpy(inputs.observations)[None]
            outputs = self.model.motion(self.times, latents, present[None], observations)[0].numpy().astype(np.float64)
        trajectory = decode_trajectory(outputs, self.config)
        if self.segment_timing is not None:  # from the median timeline to this scene's
            with torch.no_grad():
                features = self.model.motion_latents(latents, observations, present[None]).flatten().numpy()
            trajectory = segment_timing.retime(trajectory, np.asarray(self.segment_timing.knots_s),
                                               self.segment_timing.knots(features), self.config.output_fps)
        decoded = time.perf_counter()
        fit = self.scene_fit(latents, torch.from_numpy(inputs.colour), present,
                             torch.from_numpy(inputs.rgb.reshape(-1, 3)), inputs.masks, observations[..., :2], map_objects,
                             rendered)
        return {"trajectory": trajectory, "weights": weights.numpy(), "present": inputs.present,
                "object_mse": mse, "object_psnr_db": [None if m is None else psnr_db(m) for m in mse],
                **fit, "seconds": {"infer": infer_s, "decode": decoded - decoding}}

    def scene_fit(self, latents, colour, present, rgb, coarse_masks, anchors, map_objects=None,
                  rendered: dict[int, tuple] | None = None) -> dict:
        """Whole-image reconstruction PSNR and per-object IoU of the learned masks (argmax of
        the competition) with the coarse masks, at field resolution (`anchors` (1, N, 2): the
        mask centroids; `rendered`: slots already rendered for these latents; `map_objects`
        maps the other objects' rendering, by default over the worker pool)."""
        rendered = dict(rendered or {})
        missing = [slot for slot in range(self.config.num_objects) if slot not in rendered]
        with torch.no_grad():
            drawn = (map_objects or runtime.worker_pool().map)(
                lambda slot: self.model.objects[slot](self.coords[None], latents[:, slot], colour[None, slot],
                                                      anchor=anchors[:, slot], coarse=self.whole_image_residual),
                missing)
            rendered.update(zip(missing, drawn))
            scene = self.model.composite([rendered[slot] for slot in range(self.config.num_objects)], present[None],
                                         (self.bg_rgb, self.bg_logit))
        recon = scene.rgb[0]
        owner = scene.masks[0].argmax(dim=0).numpy()
        ious = []
        for slot in range(self.config.num_objects):
            if not present[slot]:
                ious.append(None)
                continue
            learned, coarse = owner == slot, coarse_masks[slot].reshape(-1)
            union = np.logical_or(learned, coarse).sum()
            ious.append(float(np.logical_and(learned, coarse).sum() / union) if union else None)
        res = self.config.field_resolution
        return {"scene_psnr_db": psnr_db(float(((recon - rgb) ** 2).mean())), "mask_iou": ious,
                "reconstruction": (recon.reshape(res, res, 3).numpy() * 255).round().astype(np.uint8),
                "learned_masks": owner.reshape(res, res).astype(np.uint8)}
