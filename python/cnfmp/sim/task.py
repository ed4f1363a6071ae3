"""What every benchmark task provides: the Task, Scene and Verdict types (the tasks by name
are in :mod:`cnfmp.sim.tasks`, the seed ranges in :mod:`cnfmp.seeds`).

A task is fully determined by (name, seed): :meth:`Task.scene` samples the variation
parameters from ``numpy.random.default_rng(seed)`` and builds the MJCF. The expert and the
judge both receive the scene, but the judge reads only physical state (body poses, contacts,
velocities) logged while the trajectory ran; it never looks at the expert's plan.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from cnfmp.errors import InputError


@dataclass
class Scene:
    """One task instance.

    Attributes:
        task: task name.
        seed: the seed it was sampled from.
        xml: the MJCF model.
        objects: names of the task objects, in label order (label k = objects[k-1]).
        object_bodies: for each object, the MuJoCo body names that make it up.
        prompt: the language instruction for this scene.
        params: the sampled variation parameters (JSON-serialisable), for the expert,
            the judge and the record.
        weld_grasp: grasp by welding the object to the gripper when the fingers close on
            it (per-task option where contact grasps prove fragile).
    """

    task: str
    seed: int
    xml: str
    objects: list[str]
    object_bodies: list[list[str]]
    prompt: str
    params: dict
    weld_grasp: bool = False


@dataclass
class Verdict:
    """A judge's decision: success, the reasons for failure (empty on success), and the
    measurements it was based on."""

    success: bool
    reasons: list[str] = field(default_factory=list)
    metrics: dict = field(default_factory=dict)


@dataclass
class Task:
    """A benchmark task: scene sampler, scripted expert and physical judge.

    `expert(scene)` returns the trajectory dict of :func:`cnfmp.geometry.path_through` at
    the control rate; `judge(scene, log)` reads a :class:`cnfmp.sim.engine.ExecutionLog`.
    """

    name: str
    description: str
    scene: Callable[[int], Scene]
    expert: Callable[[Scene], dict]
    judge: Callable[[Scene, "object"], Verdict]
    #: Whether its datasets record each episode's scan by default (`cnfmp dataset generate`
    #: without --scan / --no-scan): a task whose scenes a single image does not tell.
    records_scans: bool = False

    def __post_init__(self):
        # One line without the "name:" lead of the module docstrings, for listings.
        self.description = " ".join(self.description.split()).removeprefix(f"{self.name}: ")


def check_seed(seed: int) -> None:
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed must be a whole number >= 0, got {seed!r}")
