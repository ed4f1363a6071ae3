"""A six-joint arm of the simulator's own, for joint-space demonstrations and their check.

The benchmark's gripper floats (:mod:`cnfmp.sim.scene`); a lab's robot records joint angles.
This arm turns one into the other: inverse kinematics writes an expert's end-effector path as
joint angles (`cnfmp dataset generate --joint-space`), and forward kinematics turns a joint-
space model's prediction back into the tool pose the simulator executes and judges. The
models never see the kinematics: they learn the joint angles as recorded.

Kinematics only (unit inertias that nothing simulates, no collisions, not drawn): a base behind the table at
BASE_POSITION, a shoulder that pans about z and lifts about x, an elbow, and a three-joint
wrist (flex, roll about the forearm, twist about the fingers), ending at the tool centre point
whose +z axis points along the fingers, as the floating gripper's frame does. Angles in rad.
"""

from __future__ import annotations

import numpy as np

from cnfmp.errors import InputError

#: The arm's joints in chain order, as a recording names them (lerobot's ``<joint>.pos``).
JOINT_NAMES = ("shoulder_pan.pos", "shoulder_lift.pos", "elbow_flex.pos", "wrist_flex.pos", "wrist_roll.pos",
               "wrist_twist.pos")
#: Name of the gripper dimension beside the joints.
GRIPPER_NAME = "gripper.pos"
#: Where the base stands (m, world frame): behind the table's far edge, out of the front
#: camera's way.
BASE_POSITION = (0.0, 0.45, 0.0)
#: Inverse kinematics must reach every pose within these (m, rad) or the path is refused.
POSITION_TOLERANCE_M = 1e-4
ROTATION_TOLERANCE_RAD = 1e-3
#: Joint angles the inverse kinematics of a path starts from: elbow up, wrist bent down.
REST_ANGLES = np.array([0.0, -0.6, 1.4, -0.8, 0.0, 0.0])

_XML = f"""
<mujoco model="cnfmp-arm">
  <worldbody>
    <body name="base" pos="{' '.join(map(str, BASE_POSITION))}">
      <body name="shoulder" pos="0 0 0.25">
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
        <joint name="shoulder_pan" type="hinge" axis="0 0 1"/>
        <joint name="shoulder_lift" type="hinge" axis="1 0 0"/>
        <body name="forearm" pos="0 -0.42 0">
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
          <joint name="elbow_flex" type="hinge" axis="1 0 0"/>
          <body name="wrist" pos="0 -0.40 0">
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
            <joint name="wrist_flex" type="hinge" axis="1 0 0"/>
            <body name="hand" pos="0 -0.06 0">
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
              <joint name="wrist_roll" type="hinge" axis="0 -1 0"/>
              <body name="flange" pos="0 -0.05 0" quat="0 1 0 0">
        <inertial pos="0 0 0" mass="1" diaginertia="0.01 0.01 0.01"/>
                <joint name="wrist_twist" type="hinge" axis="0 0 1"/>
                <site name="tcp" pos="0 0 0.13"/>
              </body>
            </body>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


class Arm:
    """The arm's kinematics on a MuJoCo model of its chain (angles (T, 6) rad in JOINT_NAMES
    order; poses as positions (T, 3) m and ``[w, x, y, z]`` quaternions (T, 4))."""

    def __init__(self):
        import mujoco

        self._mujoco = mujoco
        self.model = mujoco.MjModel.from_xml_string(_XML)
        self.data = mujoco.MjData(self.model)
        self.site = self.model.site("tcp").id

    def _pose(self, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        self.data.qpos[:] = angles
        self._mujoco.mj_kinematics(self.model, self.data)
        self._mujoco.mj_comPos(self.model, self.data)  # the Jacobians read the motion axes it sets
        quat = np.empty(4)
        self._mujoco.mju_mat2Quat(quat, self.data.site_xmat[self.site])
        return self.data.site_xpos[self.site].copy(), quat

    def forward(self, angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Tool poses of joint angles (T, 6): (positions (T, 3), quaternions (T, 4), w >= 0)."""
        angles = np.asarray(angles, np.float64)
        if angles.ndim != 2 or angles.shape[1] != len(JOINT_NAMES) or not np.isfinite(angles).all():
            raise InputError(f"the arm takes finite joint angles of shape (T, {len(JOINT_NAMES)}), got {angles.shape}")
        poses = [self._pose(row) for row in angles]
        positions = np.stack([p for p, _ in poses])
        quats = np.stack([q for _, q in poses])
        return positions, np.where(quats[:, :1] < 0, -quats, quats)

    def inverse(self, positions: np.ndarray, quats: np.ndarray, start: np.ndarray = REST_ANGLES) -> np.ndarray:
        """Joint angles (T, 6) that put the tool at each pose of a path (positions (T, 3) m,
        quaternions (T, 4)), each frame's solve starting from the previous frame's angles (the
        first from `start`), so the arm moves continuously. Damped least squares on the site
        Jacobian. InputError naming the frame when a pose is out of reach."""
        from cnfmp import geometry

        mujoco = self._mujoco
        jacp, jacr = np.zeros((3, self.model.nv)), np.zeros((3, self.model.nv))
        angles = np.asarray(start, np.float64).copy()
        out = np.empty((len(positions), len(JOINT_NAMES)))
        targets = geometry.to_rotation(quats)
        for k, (goal, target) in enumerate(zip(np.asarray(positions, np.float64), targets)):
            for _ in range(200):
                position, quat = self._pose(angles)
                position_error = goal - position
                rotation_error = (target * geometry.to_rotation(quat).inv()).as_rotvec()
                if (np.linalg.norm(position_error) < POSITION_TOLERANCE_M
                        and np.linalg.norm(rotation_error) < ROTATION_TOLERANCE_RAD):
                    break
                mujoco.mj_jacSite(self.model, self.data, jacp, jacr, self.site)
                jacobian = np.vstack([jacp, jacr])
                error = np.concatenate([position_error, rotation_error])
                damping = 1e-4 * np.eye(6)
                angles = angles + jacobian.T @ np.linalg.solve(jacobian @ jacobian.T + damping, error)
            else:
                raise InputError(f"the arm cannot reach frame {k} of the path (position {np.round(goal, 3).tolist()} m): "
                                 f"{np.linalg.norm(position_error) * 1000:.1f} mm and "
                                 f"{np.degrees(np.linalg.norm(rotation_error)):.1f} deg off after 200 iterations")
            out[k] = angles
        return out


def is_arm_joints(names) -> bool:
    """Whether a motion vector's dimension names (gripper excluded) are this arm's joints."""
    return tuple(names) == JOINT_NAMES
