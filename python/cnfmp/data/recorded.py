"""Reading demonstrations as a robot recorded them: which camera, which motion vector.

A LeRobot dataset made by ``lerobot-record`` names its camera features
``observation.images.<name>`` (images or videos of any size) and its motion features
``action`` / ``observation.state`` with per-dimension names. The core learns one of two
motion forms, declared by those names; this module says which camera a dataset's scenes come
from and turns a recorded motion vector into the form the core learns:

- **end-effector pose** ``x y z qw qx qy qz gripper`` (:data:`cnfmp.data.generate.STATE_NAMES`)
  from dimensions named ``x``, ``y``, ``z`` (metres) plus a rotation, one of: a quaternion
  ``qw qx qy qz`` (any order of the four names), a rotation vector ``rx ry rz`` (axis times
  angle, rad), or Euler angles ``roll pitch yaw`` (rad, the fixed-axis x-y-z convention of
  ROS / URDF: R = Rz(yaw) Ry(pitch) Rx(roll));
- **joint space**: a vector with none of those names, whose every dimension but the gripper
  is a joint (``shoulder_pan.pos`` ...), learned as recorded (radians, metres or motor units:
  the core standardises each dimension) with the joints in the recording's order, then the
  gripper.

Either way the gripper is one dimension whose name contains ``gripper``, kept as it is when
recorded in [0, 1], else rescaled to [0, 1] over the dataset's range. Names match after
lower-casing and dropping a prefix such as ``ee.`` / ``eef_`` / ``end_effector.`` and a
``.pos`` suffix.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from cnfmp.errors import InputError

#: Where a trajectory may come from.
MOTION_SOURCES = ("action", "observation.state")
#: The rotation forms a layout may declare, with the names of their dimensions in order.
ROTATION_FORMS = {"quaternion": ("qw", "qx", "qy", "qz"), "rotvec": ("rx", "ry", "rz"),
                  "euler": ("roll", "pitch", "yaw")}
#: MotionLayout.rotation of a joint-space layout (no end-effector rotation).
JOINTS = "joints"
_PREFIX = re.compile(r"^(ee|eef|end_effector|tcp|tool)[._]")
_SUFFIX = re.compile(r"[._]pos$")


def _plain(name: str) -> str:
    return _SUFFIX.sub("", _PREFIX.sub("", str(name).strip().lower()))


@dataclass(frozen=True)
class MotionLayout:
    """Where each part of the motion the core learns sits in a recorded motion vector.

    Attributes:
        source: the dataset feature read (one of MOTION_SOURCES).
        names: the vector's dimension names as recorded or declared.
        position: indices of x, y, z (empty in joint space).
        rotation: "quaternion", "rotvec" or "euler" (see ROTATION_FORMS), or JOINTS.
        rotation_indices: indices of the rotation's dimensions, in ROTATION_FORMS order
            (empty in joint space).
        gripper: index of the gripper dimension.
        joints: indices of the joints, in the recording's order (empty for a pose).
    """

    source: str
    names: tuple[str, ...]
    position: tuple[int, ...]
    rotation: str
    rotation_indices: tuple[int, ...]
    gripper: int
    joints: tuple[int, ...] = ()

    @property
    def joint_names(self) -> list[str]:
        """The joints' names as recorded (empty for a pose)."""
        return [self.names[k] for k in self.joints]

    def describe(self) -> str:
        """One line for logs and the model card, e.g. ``action: x y z rx ry rz gripper (rotvec)``."""
        form = f"{len(self.joints)} joints" if self.rotation == JOINTS else self.rotation
        return f"{self.source}: {' '.join(self.names)} ({form})"


def motion_layout(source: str, names) -> MotionLayout:
    """The layout of the motion vector `source` whose dimensions are called `names` (a list,
    or lerobot's ``{"motors": [...]}`` form). InputError naming what is missing or unsupported.
    """
    if source not in MOTION_SOURCES:
        raise InputError(f"the motion comes from one of {', '.join(MOTION_SOURCES)}, not {source!r}")
    if isinstance(names, dict):
        names = [n for group in names.values() for n in group]
    if not names:
        raise InputError(f"{source} does not name its dimensions; declare them, e.g. "
                         "--motion-names x,y,z,rx,ry,rz,gripper")
    names = tuple(str(n) for n in names)
    plain = [_plain(n) for n in names]
    where = {name: k for k, name in enumerate(plain)}
    missing = [axis for axis in ("x", "y", "z") if axis not in where]
    grippers = [k for k, name in enumerate(plain) if "gripper" in name]
    forms = [form for form, parts in ROTATION_FORMS.items() if all(p in where for p in parts)]
    if len(grippers) != 1:
        raise InputError(f"{source} ({', '.join(names)}) needs exactly one dimension named like 'gripper', "
                         f"found {len(grippers)}")
    pose_names = {"x", "y", "z", *(p for parts in ROTATION_FORMS.values() for p in parts)}
    if not pose_names & set(where):
        joints = tuple(k for k in range(len(names)) if k != grippers[0])
        if not joints:
            raise InputError(f"{source} ({', '.join(names)}) has only a gripper: no joint or pose to learn")
        if len(set(plain)) != len(plain):
            raise InputError(f"{source} ({', '.join(names)}) names two dimensions alike; declare distinct "
                             "names with --motion-names")
        return MotionLayout(source, names, (), JOINTS, (), grippers[0], joints)
    if missing or not forms:
        raise InputError(
            f"{source} ({', '.join(names)}) is neither an end-effector pose nor joint space: "
            + (f"no {'/'.join(missing)} position dimension(s)" if missing else "no rotation")
            + ". A pose is x, y, z plus a quaternion (qw qx qy qz), a rotation vector (rx ry rz) "
              "or Euler angles (roll pitch yaw), plus a gripper; a joint-space vector uses none of these names. "
              "If the names differ, declare them with --motion-names")
    form = forms[0]
    return MotionLayout(source, names, (where["x"], where["y"], where["z"]), form,
                        tuple(where[p] for p in ROTATION_FORMS[form]), grippers[0])


def _quaternions(values: np.ndarray, layout: MotionLayout) -> np.ndarray:
    """(T, 4) unit ``wxyz`` quaternions of the rotation part of (T, D) `values`."""
    from cnfmp import geometry

    part = values[:, list(layout.rotation_indices)].astype(np.float64)
    if layout.rotation == "quaternion":
        norms = np.linalg.norm(part, axis=1, keepdims=True)
        if np.any(norms < 1e-6):
            raise InputError(f"{layout.source} holds a zero quaternion")
        quat = part / norms
    elif layout.rotation == "rotvec":
        quat = geometry.from_rotation(geometry.Rotation.from_rotvec(part))
    else:
        quat = geometry.from_rotation(geometry.Rotation.from_euler("xyz", part))
    # Keep consecutive quaternions on one hemisphere, so the motion has no sign jumps.
    for k in range(1, len(quat)):
        if np.dot(quat[k], quat[k - 1]) < 0:
            quat[k] = -quat[k]
    return quat


def to_motion(episodes: list[np.ndarray], layout: MotionLayout) -> tuple[list[np.ndarray], tuple[float, float] | None]:
    """Every episode's (T_b, D) motion vectors in the form the core learns: (T_b, 8)
    ``x y z qw qx qy qz gripper`` poses, or in joint space (T_b, J + 1) the joints in the
    layout's order then the gripper.

    A gripper recorded in [0, 1] is kept as it is (a constant one too: a task without a
    grasp). Any other range (millimetres, 0-100, motor units) is rescaled linearly to [0, 1]
    over the dataset's range, low to 0. Returns (poses, the recorded (low, high) mapped to
    (0, 1), or None when kept). InputError for a gripper in other units that never moves:
    most likely the wrong dimension.
    """
    grippers = np.concatenate([e[:, layout.gripper] for e in episodes]).astype(np.float64)
    low, high = float(grippers.min()), float(grippers.max())
    scale = None if (low >= 0.0 and high <= 1.0) else (low, high)
    if scale is not None and high - low < 1e-9:
        raise InputError(f"{layout.source}'s gripper ({layout.names[layout.gripper]}) stays at {low:g} in every "
                         "episode, outside [0, 1], so open and closed cannot be told apart; check the dimension "
                         "names (--motion-names) or record the gripper as an opening in [0, 1]")
    poses = []
    for values in episodes:
        values = np.asarray(values, np.float64)
        gripper = values[:, layout.gripper]
        if scale is not None:
            gripper = (gripper - low) / (high - low)
        if layout.rotation == JOINTS:
            poses.append(np.concatenate([values[:, list(layout.joints)], gripper[:, None]], axis=1))
            continue
        poses.append(np.concatenate([values[:, list(layout.position)], _quaternions(values, layout),
                                     gripper[:, None]], axis=1))
    return poses, scale


def from_motion(poses: np.ndarray, layout: MotionLayout, gripper_range: tuple[float, float] | None) -> tuple[list[str], np.ndarray]:
    """(T, 8) ``x y z qw qx qy qz gripper`` poses, or (T, J + 1) joints + gripper, back in the
    recording's form: the names of the dimensions the layout uses, in the recording's order,
    and (T, len(names)) values (rotation as recorded, gripper in the recording's units; the
    inverse of :func:`to_motion`)."""
    from cnfmp import geometry

    poses = np.asarray(poses, np.float64)
    if layout.rotation == JOINTS:
        columns = dict(zip(layout.joints, poses[:, :-1].T))
    else:
        columns = dict(zip(layout.position, poses[:, :3].T))
        columns.update(zip(layout.rotation_indices, _recorded_rotation(poses[:, 3:7], layout).T))
    gripper = poses[:, -1]
    if gripper_range is not None:
        gripper = gripper_range[0] + gripper * (gripper_range[1] - gripper_range[0])
    columns[layout.gripper] = gripper
    order = sorted(columns)
    return [layout.names[k] for k in order], np.stack([columns[k] for k in order], axis=1)


def _recorded_rotation(quats: np.ndarray, layout: MotionLayout) -> np.ndarray:
    """(T, 4) ``wxyz`` quaternions in the layout's rotation form: (T, 4) or (T, 3)."""
    from cnfmp import geometry

    if layout.rotation == "quaternion":
        return quats
    if layout.rotation == "rotvec":
        rotation = geometry.to_rotation(quats).as_rotvec()
        # Near half a turn, v and v (1 - 2 pi / |v|) are the same rotation: keep the one
        # closest to the previous frame's, so a robot interpolating the values never flips.
        for k in range(1, len(rotation)):
            angle = np.linalg.norm(rotation[k])
            if angle > 1e-9:
                other = rotation[k] * (1 - 2 * np.pi / angle)
                if np.linalg.norm(other - rotation[k - 1]) < np.linalg.norm(rotation[k] - rotation[k - 1]):
                    rotation[k] = other
        return rotation
    return np.unwrap(geometry.to_rotation(quats).as_euler("xyz"), axis=0)


def camera_keys(features: dict) -> list[str]:
    """The dataset's camera features (``image`` or ``video``), in the dataset's order; a
    scan's packed depth views (``annotation.*``, :mod:`cnfmp.scan`) are not cameras."""
    return [key for key, spec in features.items()
            if spec.get("dtype") in ("image", "video") and not key.startswith("annotation.")]


def choose_camera(features: dict, requested: str | None, annotated: str | None) -> str:
    """The camera whose first frames are the demonstrations' scenes.

    Args:
        features: the dataset's feature specs; requested: ``--camera`` (None: not given);
        annotated: the camera the masks were made on, when the dataset records it.

    The masks belong to one camera's pixels, so a request for another is refused. Without
    either, the only camera; several: InputError listing them.
    """
    cameras = camera_keys(features)
    if not cameras:
        raise InputError("the dataset has no camera (image or video) feature")
    if requested is not None and requested not in cameras:
        raise InputError(f"the dataset has no camera {requested!r}; its cameras: {', '.join(cameras)}")
    if annotated is not None:
        if requested is not None and requested != annotated:
            raise InputError(f"the dataset's masks were made on camera {annotated!r}, not {requested!r}; "
                             f"annotate {requested!r} into a new dataset with `cnfmp dataset annotate --camera {requested}`")
        return annotated
    if requested is not None:
        return requested
    if len(cameras) > 1:
        raise InputError(f"the dataset has {len(cameras)} cameras ({', '.join(cameras)}); choose one with --camera")
    return cameras[0]
