"""The MuJoCo benchmark: five tasks built in code, scripted experts, physical judges.

Modules: `scene` (table, camera, gripper), `engine` (scene image, masks, executing a
trajectory), `task` (the Task/Scene/Verdict types), `tasks/` (one module per task and the
registry of them by name), `api` (the entry points the Rust bridge calls). The seed ranges
are in :mod:`cnfmp.seeds`.
"""

from cnfmp.runtime import choose_gl_backend

# MuJoCo binds its GL backend when first imported; without a display only EGL or OSMesa
# work, so choose before anything below imports mujoco (the user's MUJOCO_GL wins).
choose_gl_backend()
