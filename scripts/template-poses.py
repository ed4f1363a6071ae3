"""How a core model's object template sits in each scene: the turn, scale and stretch that
the object's latent gives its template (the linear part of the deformation, for models with
`full_turns`), next to the simulator's parameters of that scene.

Run it on the model's training scenes (the latents training learned for each demonstration;
seeds from 0, as `cnfmp sim generate` numbers them) to see what the latent encodes, and on
validation scenes (the latents inference finds; by default from the first validation seed)
to see where a new scene lands. Held-out seeds are refused, so nothing is tuned on them.

    .venv/bin/python scripts/template-poses.py --model models/incline_pick_place --slot 2
    .venv/bin/python scripts/template-poses.py --model models/incline_pick_place --slot 2 \\
        --validation --scenes 20

Prints one line per scene: seed, template turn (deg), scale, stretch, then every scalar
scene parameter (angles in deg where the name says yaw or slope).
"""

from __future__ import annotations

import argparse

import numpy as np

from cnfmp import runtime

runtime.configure(threads=1)  # before torch loads: one thread, deterministic kernels, as the CLI runs

import torch  # noqa: E402

from cnfmp.core import api as core, data as core_data, trial  # noqa: E402
from cnfmp.core.modeling_cnfmp import STRETCH_BOUND  # noqa: E402
from cnfmp.images import decode_image, decode_labels  # noqa: E402
from cnfmp.seeds import VALIDATION_SEEDS  # noqa: E402
from cnfmp.sim.tasks import get_task  # noqa: E402


def template_pose(field, latent: torch.Tensor) -> tuple[float, float, float, float]:
    """An object field's template pose for one latent (D,): turn (deg, in (-180, 180]),
    scale, and the two stretch terms (see ObjectField.canonical with `full_turns`)."""
    with torch.no_grad():
        u, v, a, b = field.linear(latent).tolist()
    turn = float(np.degrees(np.arctan2(v, 1.0 + u)))
    return turn, float(np.hypot(1.0 + u, v)), STRETCH_BOUND * float(np.tanh(a)), STRETCH_BOUND * float(np.tanh(b))


def scene_summary(task: str, seed: int) -> str:
    """The scene's scalar parameters, angles in degrees."""
    parts = []
    for name, value in get_task(task).scene(seed).params.items():
        if np.ndim(value) == 0 and isinstance(value, (int, float, np.floating)):
            shown = np.degrees(value) if ("yaw" in name or "slope" in name) else value
            parts.append(f"{name} {shown:.1f}")
    return ", ".join(parts)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", required=True, help="core model directory (cnfmp, full_turns)")
    parser.add_argument("--slot", type=int, required=True, help="object slot, from 1 (objects.json order)")
    parser.add_argument("--validation", action="store_true",
                        help="infer the latents of validation scenes instead of reading the training latents")
    parser.add_argument("--seed-start", type=int, default=None,
                        help=f"first scene seed (default: 0 for training scenes, {VALIDATION_SEEDS.start} for --validation)")
    parser.add_argument("--scenes", type=int, default=None,
                        help="scenes to show (default: every demonstration; 20 with --validation)")
    args = parser.parse_args()
    predictor = core.predictor(args.model)
    model, config = predictor.model, predictor.config
    if not getattr(config, "full_turns", False):
        parser.error(f"{args.model} is not a cnfmp model with full_turns; its template has no turn to read")
    if not 1 <= args.slot <= config.num_objects:
        parser.error(f"--slot must be in 1..{config.num_objects} ({', '.join(config.object_names)})")
    slot = args.slot - 1
    demos = model.demo_logits.shape[0]
    seed_start = args.seed_start if args.seed_start is not None else (VALIDATION_SEEDS.start if args.validation else 0)
    scenes = args.scenes or (20 if args.validation else demos)
    problem = trial.validation_range_error(seed_start, scenes)
    if problem:
        parser.error(problem)
    if not args.validation and scenes > demos:
        parser.error(f"the model has {demos} demonstrations; --scenes must be at most that")
    field = model.objects[slot]
    for index, seed in enumerate(range(seed_start, seed_start + scenes)):
        if args.validation:
            image, labels, _ = trial.render(config.task, seed)
            inputs = core_data.scene_inputs(decode_image(image), decode_labels(labels), config.num_objects,
                                            config.field_resolution, config.mask_dilation)
            weights = predictor.infer_scene(inputs, seed=0)[0][slot]
        else:
            weights = torch.softmax(model.demo_logits[index, slot], dim=-1)
        turn, scale, stretch_a, stretch_b = template_pose(field, model.object_latent(slot, weights[None])[0])
        print(f"seed {seed}: turn {turn:7.1f} deg, scale {scale:.2f}, stretch {stretch_a:+.2f} {stretch_b:+.2f} | "
              f"{scene_summary(config.task, seed)}", flush=True)


if __name__ == "__main__":
    main()
