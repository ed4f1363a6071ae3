"""Scene construction shared by every task: table, camera, the floating parallel-jaw gripper.

World frame: metres, z up, table top at z = 0; the camera looks at the table from the front
(-y side); three more cameras (left, right, top) see it for 3D scans. The gripper is a free body welded (softly) to a mocap target, so it is dynamic and
its contacts are real: a wall it brushes reports a contact. Its frame's origin is the tool
centre point (between the fingertips) and its +z axis points along the fingers; the
trajectory poses are this frame's poses. Fingers slide along the gripper's y axis and are
driven by position actuators: command 1 = fully open.
"""

from __future__ import annotations

import numpy as np

from cnfmp import geometry

#: Physics step (s). 2 ms keeps finger contacts stable (facts.md).
TIMESTEP = 0.002
#: Rate at which trajectories are executed (Hz): one mocap target per control step.
CONTROL_HZ = 50
#: Half the maximum finger gap (m): the opening of each finger at gripper command 1.
FINGER_TRAVEL = 0.045
#: Camera image size (pixels).
IMAGE_SIZE = 128
#: The fixed front camera: position (m), image x and y axes in the world frame (MuJoCo's
#: ``xyaxes``; the camera looks along -(x cross y)), vertical field of view (degrees).
CAMERA_POSITION = (0.0, -0.42, 0.50)
CAMERA_XYAXES = (1.0, 0.0, 0.0, 0.0, 0.76, 0.65)
CAMERA_FOVY_DEG = 45.0
_CAMERA_POS, _CAMERA_XYAXES = (" ".join(map(str, v)) for v in (CAMERA_POSITION, CAMERA_XYAXES))
#: The other fixed cameras of a scan (:mod:`cnfmp.sim.scan`), beside "front": name ->
#: (position, the point it looks at), metres; the same field of view and image size.
SCAN_CAMERAS = {
    "left": ((-0.55, -0.15, 0.45), (0.0, 0.08, 0.05)),
    "right": ((0.55, -0.15, 0.45), (0.0, 0.08, 0.05)),
    "top": ((0.0, -0.10, 0.85), (0.0, 0.06, 0.0)),
}


def look_at_xyaxes(position, target) -> tuple[float, ...]:
    """MuJoCo's ``xyaxes`` of a camera at `position` looking at `target` with the world's z
    up in its image: its x axis (image right) then y axis (image up); it looks along -z."""
    forward = np.asarray(target, float) - np.asarray(position, float)
    forward /= np.linalg.norm(forward)
    x_axis = np.cross(forward, [0.0, 0.0, 1.0])
    x_axis /= np.linalg.norm(x_axis)
    return (*x_axis, *np.cross(x_axis, forward))


def _scan_cameras_xml() -> str:
    return "".join(
        f'\n    <camera name="{name}" pos="{" ".join(f"{v:.6f}" for v in position)}" '
        f'xyaxes="{" ".join(f"{v:.6f}" for v in look_at_xyaxes(position, target))}" fovy="{CAMERA_FOVY_DEG}"/>'
        for name, (position, target) in SCAN_CAMERAS.items())
#: Gripper pose at the start of every expert trajectory: above the table, fingers down.
HOME_POSITION = np.array([0.0, -0.05, 0.40])
HOME_QUAT = geometry.quat_down(0.0)
#: Where the gripper waits while the scene image is rendered: out of the camera's view.
PARK_POSITION = np.array([0.0, -1.5, 1.5])
#: Workspace a trajectory must stay inside (m): [[x_min, y_min, z_min], [x_max, y_max, z_max]].
WORKSPACE = np.array([[-0.45, -0.40, -0.005], [0.45, 0.40, 0.70]])

GRIPPER_GEOM_PREFIX = "gripper_"


def gripper_xml(position=HOME_POSITION, quat=HOME_QUAT) -> tuple[str, str, str]:
    """MJCF for the gripper: (worldbody part, actuator part, equality part)."""
    pos = " ".join(f"{v:.6f}" for v in position)
    q = " ".join(f"{v:.6f}" for v in quat)
    # Fingers: 1 cm wide (x), 1.2 cm thick (y), 6 cm long (z), fingertips at the TCP.
    finger = (
        '<geom name="gripper_{side}_pad" type="box" size="0.011 0.006 0.03" pos="0 {y} -0.027" '
        'rgba="0.25 0.25 0.28 1" friction="1.5 0.02 0.001" condim="4" mass="0.03"/>'
    )
    world = f"""
    <body name="gripper_target" mocap="true" pos="{pos}" quat="{q}"/>
    <body name="gripper" pos="{pos}" quat="{q}" gravcomp="1">
      <freejoint name="gripper_free"/>
      <geom name="gripper_palm" type="box" size="0.015 0.06 0.012" pos="0 0 -0.07" rgba="0.3 0.3 0.33 1" mass="0.4"/>
      <geom name="gripper_wrist" type="cylinder" size="0.02 0.03" pos="0 0 -0.11" rgba="0.3 0.3 0.33 1" mass="0.1"/>
      <body name="gripper_left" pos="0 0 0" gravcomp="1">
        <joint name="finger_left" type="slide" axis="0 1 0" range="0 {FINGER_TRAVEL}" damping="5" armature="0.01"/>
        {finger.format(side="left", y=0.006)}
      </body>
      <body name="gripper_right" pos="0 0 0" gravcomp="1">
        <joint name="finger_right" type="slide" axis="0 -1 0" range="0 {FINGER_TRAVEL}" damping="5" armature="0.01"/>
        {finger.format(side="right", y=-0.006)}
      </body>
    </body>"""
    actuators = f"""
    <position name="finger_left" joint="finger_left" kp="400" ctrlrange="0 {FINGER_TRAVEL}" forcerange="-25 25"/>
    <position name="finger_right" joint="finger_right" kp="400" ctrlrange="0 {FINGER_TRAVEL}" forcerange="-25 25"/>"""
    equality = """
    <weld name="gripper_follow" body1="gripper" body2="gripper_target" relpose="0 0 0 1 0 0 0" solref="0.008 1" solimp="0.95 0.99 0.001"/>"""
    return world, actuators, equality


def scene_xml(objects: str, extra_equality: str = "", table_rgba: str = "0.72 0.62 0.50 1",
              gripper_position=HOME_POSITION, gripper_quat=HOME_QUAT) -> str:
    """A full MJCF model: the shared table, light, camera and gripper around task `objects`,
    the gripper starting at (`gripper_position`, `gripper_quat`), fully open."""
    gripper, actuators, equality = gripper_xml(gripper_position, gripper_quat)
    return f"""
<mujoco model="cnfmp">
  <option timestep="{TIMESTEP}" cone="elliptic" impratio="10" noslip_iterations="3"/>
  <visual>
    <global offwidth="{IMAGE_SIZE}" offheight="{IMAGE_SIZE}"/>
    <quality shadowsize="1024"/>
    <headlight ambient="0.45 0.45 0.45" diffuse="0.5 0.5 0.5"/>
  </visual>
  <worldbody>
    <light pos="0.3 -0.4 1.5" dir="-0.2 0.25 -1" diffuse="0.5 0.5 0.5" castshadow="false"/>
    <camera name="front" pos="{_CAMERA_POS}" xyaxes="{_CAMERA_XYAXES}" fovy="{CAMERA_FOVY_DEG}"/>{_scan_cameras_xml()}
    <geom name="floor" type="plane" size="2 2 0.1" pos="0 0 -0.75" rgba="0.35 0.36 0.38 1"/>
    <geom name="table" type="box" size="0.5 0.42 0.02" pos="0 0 -0.02" rgba="{table_rgba}" friction="1 0.005 0.0001"/>
    {objects}
    {gripper}
  </worldbody>
  <actuator>{actuators}
  </actuator>
  <equality>{equality}{extra_equality}
  </equality>
</mujoco>
"""


def project_to_image(points: np.ndarray) -> np.ndarray:
    """World points (N, 3) in metres -> (N, 2) pixel coordinates [column, row] of the front
    camera's IMAGE_SIZE x IMAGE_SIZE image (pinhole model, as MuJoCo renders it; pixel centres
    at +0.5). Points behind the camera come out as NaN."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x_axis, y_axis = np.array(CAMERA_XYAXES[:3]), np.array(CAMERA_XYAXES[3:])
    x_axis /= np.linalg.norm(x_axis)
    y_axis -= x_axis * (x_axis @ y_axis)
    y_axis /= np.linalg.norm(y_axis)
    z_axis = np.cross(x_axis, y_axis)
    offset = points - np.array(CAMERA_POSITION)
    depth = -(offset @ z_axis)
    focal = 0.5 * IMAGE_SIZE / np.tan(np.radians(CAMERA_FOVY_DEG) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        column = 0.5 * IMAGE_SIZE + focal * (offset @ x_axis) / depth
        row = 0.5 * IMAGE_SIZE - focal * (offset @ y_axis) / depth
    pixels = np.stack([column, row], axis=1)
    pixels[depth <= 0] = np.nan
    return pixels
