"""The benchmark tasks by name: one module per task, each defining its :class:`Task` as
``TASK``, and this registry, which imports them on first use (they pull in MuJoCo)."""

from __future__ import annotations

import functools

from cnfmp.errors import InputError
from cnfmp.sim.task import Task


@functools.cache
def _tasks() -> dict[str, Task]:
    from cnfmp.sim.tasks import (bar_into_tray, cube_stacking, cup_stacking, drawer_place, incline_pick_place, language_pick_place,
                                 wall_avoidance)

    modules = (bar_into_tray, cube_stacking, cup_stacking, drawer_place, incline_pick_place, language_pick_place, wall_avoidance)
    return {module.TASK.name: module.TASK for module in modules}


def get_task(name: str) -> Task:
    """The task called `name`; InputError naming the known tasks otherwise."""
    try:
        return _tasks()[name]
    except KeyError:
        raise InputError(f"unknown task {name!r}; known tasks: {', '.join(task_names())}") from None


def task_names() -> list[str]:
    return sorted(_tasks())


__all__ = ["get_task", "task_names"]
