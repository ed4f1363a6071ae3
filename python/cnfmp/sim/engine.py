"""Running a scene: the scene image and object masks, and executing a trajectory by physics.

A trajectory is executed at :data:`scene.CONTROL_HZ`: each control step sets the gripper's
mocap target and finger command, then steps physics ``1 / (CONTROL_HZ * TIMESTEP)`` times.
After the last frame the command is held while everything settles, then the task's judge
reads the :class:`ExecutionLog`: per-step gripper and object poses, every pair of bodies that
touched at any physics step, and the final state.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from cnfmp import geometry
from cnfmp.errors import InputError
from cnfmp.sim import scene as sc
from cnfmp.sim.task import Scene

SUBSTEPS = round(1.0 / (sc.CONTROL_HZ * sc.TIMESTEP))
#: Time the last command is held before judging (s).
SETTLE_S = 1.0
#: Gripper commands below this count as closed; a release is the step a closed command opens.
CLOSED_BELOW = 0.5
#: Grasp-weld activation: the object must touch both finger pads.
_PADS = ("gripper_left_pad", "gripper_right_pad")


@dataclass
class ExecutionLog:
    """What happened, for the judge. Per-control-step arrays have T rows.

    Attributes:
        ee_position: (T, 3) gripper TCP position (m), measured.
        ee_quat: (T, 4) gripper orientation, wxyz, measured.
        finger_opening: (T,) finger opening in [0, 1] (1 = fully open), measured.
        gripper_command: (T,) commanded opening.
        object_position: name -> (T, 3) object body position (first body of the object).
        touched: set of frozenset({body_a, body_b}) that were in contact at any physics step,
            settling included.
        final_position / final_quat: name -> object pose after settling.
        final_speed: name -> linear speed (m/s) after settling.
        final_finger_contacts: object names touching a finger pad after settling.
        release_step: the first control step at which the gripper command went from closed
            (< CLOSED_BELOW) to open (None if it never did); release_quat: the measured gripper
            orientation at that step.
    """

    ee_position: np.ndarray
    ee_quat: np.ndarray
    finger_opening: np.ndarray
    gripper_command: np.ndarray
    object_position: dict
    touched: set
    final_position: dict
    final_quat: dict
    final_speed: dict
    final_finger_contacts: set
    release_step: int | None
    release_quat: np.ndarray | None

    def touched_any(self, bodies_a, bodies_b) -> bool:
        """True if any body in `bodies_a` touched any body in `bodies_b` at any step."""
        return any(frozenset((a, b)) in self.touched for a in bodies_a for b in bodies_b)


class Simulation:
    """A MuJoCo model and state for one scene, with its camera renderer."""

    def __init__(self, scene: Scene):
        self.scene = scene
        self.model = mujoco.MjModel.from_xml_string(scene.xml)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self._mocap = m.body_mocapid[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "gripper_target")]
        self._gripper_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "gripper")
        self._gripper_qpos = m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, "gripper_free")]
        self._fingers = [m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)] for n in ("finger_left", "finger_right")]
        self._pad_geoms = {mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, n) for n in _PADS}
        body = lambda name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)  # noqa: E731
        self._object_bodies = [[body(n) for n in names] for names in scene.object_bodies]
        if any(b < 0 for bodies in self._object_bodies for b in bodies):
            raise RuntimeError(f"{scene.task}: an object body is missing from the model")
        self._body_label = np.zeros(m.nbody, dtype=np.uint8)
        for label, bodies in enumerate(self._object_bodies, start=1):
            self._body_label[bodies] = label
        self._welds = {}
        if scene.weld_grasp:
            for name, bodies in zip(scene.objects, scene.object_bodies):
                eq = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_EQUALITY, f"grasp_{bodies[0]}")
                if eq >= 0:
                    self._welds[bodies[0]] = eq
        self._renderer = None
        self.data.ctrl[:] = sc.FINGER_TRAVEL
        self.data.qpos[self._fingers] = sc.FINGER_TRAVEL
        mujoco.mj_forward(m, self.data)

    # --- camera ---------------------------------------------------------------------------
    def set_camera_size(self, width: int, height: int) -> None:
        """Renders from now on at `width` x `height` px instead of the benchmark's square
        IMAGE_SIZE, with the same vertical field of view (a wider image sees more of the
        table at the sides); a lab-like camera for the re-recorded benchmark."""
        self.model.vis.global_.offwidth, self.model.vis.global_.offheight = width, height
        if self._renderer is not None:
            self._renderer.close()
        self._renderer = mujoco.Renderer(self.model, height, width)

    def _render(self, segmentation: bool, camera: str = "front", depth: bool = False) -> np.ndarray:
        if self._renderer is None:
            self._renderer = mujoco.Renderer(self.model, sc.IMAGE_SIZE, sc.IMAGE_SIZE)
        if segmentation:
            self._renderer.enable_segmentation_rendering()
        else:
            self._renderer.disable_segmentation_rendering()
        if depth:
            self._renderer.enable_depth_rendering()
        else:
            self._renderer.disable_depth_rendering()
        self._renderer.update_scene(self.data, camera=camera)
        return self._renderer.render()

    def render_rgb(self, camera: str = "front") -> np.ndarray:
        """(128, 128, 3) uint8 camera image of the current state."""
        return self._render(segmentation=False, camera=camera).copy()

    def render_depth(self, camera: str = "front") -> np.ndarray:
        """(128, 128) float32 depth of the current state along the camera's optical axis (m)."""
        return self._render(segmentation=False, camera=camera, depth=True).astype(np.float32)

    def render_labels(self, camera: str = "front") -> np.ndarray:
        """(128, 128) uint8 label map of the current state: 0 background (and the gripper),
        k where the k-th object is visible."""
        seg = self._render(segmentation=True, camera=camera)
        geom_ids, types = seg[..., 0], seg[..., 1]
        is_geom = (types == int(mujoco.mjtObj.mjOBJ_GEOM)) & (geom_ids >= 0)
        labels = np.zeros(geom_ids.shape, dtype=np.uint8)
        labels[is_geom] = self._body_label[self.model.geom_bodyid[geom_ids[is_geom]]]
        return labels

    def render_scene(self) -> tuple[np.ndarray, np.ndarray]:
        """The scene image with the gripper parked out of view, and its label map
        (see :meth:`render_labels`). The physical state is restored afterwards."""
        (rgb, _, labels), = self.render_views(["front"], depth=False)
        return rgb, labels

    def render_views(self, cameras: list[str], depth: bool = True) -> list[tuple]:
        """Per camera (MJCF names) the (rgb, depth or None, labels) of :meth:`render_rgb`,
        :meth:`render_depth` and :meth:`render_labels`, with the gripper parked out of view;
        the physical state is restored afterwards."""
        saved_qpos, saved_mocap = self.data.qpos.copy(), self.data.mocap_pos.copy()
        adr = self._gripper_qpos
        self.data.qpos[adr:adr + 3] = sc.PARK_POSITION
        self.data.mocap_pos[self._mocap] = sc.PARK_POSITION
        mujoco.mj_forward(self.model, self.data)
        try:
            return [(self.render_rgb(camera), self.render_depth(camera) if depth else None, self.render_labels(camera))
                    for camera in cameras]
        finally:
            self.data.qpos[:], self.data.mocap_pos[:] = saved_qpos, saved_mocap
            mujoco.mj_forward(self.model, self.data)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    # --- execution ------------------------------------------------------------------------
    def execute(self, trajectory: dict, frame_every: int = 0) -> tuple[ExecutionLog, list]:
        """Runs `trajectory` (at CONTROL_HZ; keys position (T,3), orientation (T,4) wxyz,
        gripper (T,)), settles for SETTLE_S, and returns the log, plus every `frame_every`
        control steps (starting with step 0; none when 0) the camera image and label map
        as an (rgb, labels) pair, taken after the step's physics.

        Raises InputError when a pose leaves :data:`scene.WORKSPACE` or a value is not finite.
        """
        position, quat, command = _checked(trajectory)
        m, d = self.model, self.data
        steps = len(position)
        names = self.scene.objects
        first_bodies = [bodies[0] for bodies in self._object_bodies]
        ee_pos, ee_quat = np.zeros((steps, 3)), np.zeros((steps, 4))
        opening, obj_pos = np.zeros(steps), np.zeros((len(names), steps, 3))
        touched = np.zeros((m.nbody, m.nbody), dtype=bool)
        frames: list[tuple[np.ndarray, np.ndarray]] = []
        release_step, release_quat, was_closed = None, None, False
        settle_steps = round(SETTLE_S * sc.CONTROL_HZ)
        for k in range(steps + settle_steps):
            j = min(k, steps - 1)
            d.mocap_pos[self._mocap] = position[j]
            d.mocap_quat[self._mocap] = quat[j]
            d.ctrl[:] = command[j] * sc.FINGER_TRAVEL
            closed = command[j] < CLOSED_BELOW
            if k < steps and was_closed and not closed and release_step is None:
                release_step, release_quat = k, d.xquat[self._gripper_body].copy()
            was_closed = closed if k < steps else was_closed
            if self._welds:
                self._update_weld(closed)
            for _ in range(SUBSTEPS):
                mujoco.mj_step(m, d)
                n = d.ncon
                if n:
                    b1 = m.geom_bodyid[d.contact.geom1[:n]]
                    b2 = m.geom_bodyid[d.contact.geom2[:n]]
                    touched[b1, b2] = True
            if k < steps:
                ee_pos[k] = d.xpos[self._gripper_body]
                ee_quat[k] = d.xquat[self._gripper_body]
                opening[k] = d.qpos[self._fingers].mean() / sc.FINGER_TRAVEL
                obj_pos[:, k] = d.xpos[first_bodies]
                if frame_every and k % frame_every == 0:
                    frames.append((self.render_rgb(), self.render_labels()))
        touched |= touched.T
        body_name = lambda b: mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b)  # noqa: E731
        pairs = {frozenset((body_name(a), body_name(b))) for a, b in zip(*np.nonzero(np.triu(touched)))}
        speeds = {}
        for name, bodies in zip(names, self._object_bodies):
            vel = np.zeros(6)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, bodies[0], vel, 0)
            speeds[name] = float(np.linalg.norm(vel[3:]))
        log = ExecutionLog(
            ee_position=ee_pos, ee_quat=ee_quat, finger_opening=opening, gripper_command=command,
            object_position={n: obj_pos[i] for i, n in enumerate(names)},
            touched=pairs,
            final_position={n: d.xpos[b[0]].copy() for n, b in zip(names, self._object_bodies)},
            final_quat={n: d.xquat[b[0]].copy() for n, b in zip(names, self._object_bodies)},
            final_speed=speeds,
            final_finger_contacts=self._objects_touching_pads(),
            release_step=release_step, release_quat=release_quat,
        )
        return log, frames

    def _objects_touching_pads(self) -> set:
        d, m = self.data, self.model
        found = set()
        for i in range(d.ncon):
            g1, g2 = d.contact.geom1[i], d.contact.geom2[i]
            for pad, other in ((g1, g2), (g2, g1)):
                if pad in self._pad_geoms:
                    label = self._body_label[m.geom_bodyid[other]]
                    if label:
                        found.add(self.scene.objects[label - 1])
        return found

    def _update_weld(self, closed: bool) -> None:
        """Weld-on-close grasp: when the fingers close on an object (touching both pads),
        fix it to the gripper in its current relative pose; release when they open."""
        d, m = self.data, self.model
        active = [eq for eq in self._welds.values() if d.eq_active[eq]]
        if not closed:
            for eq in active:
                d.eq_active[eq] = 0
            return
        if active:
            return
        pads_touching: dict[int, set] = {}
        for i in range(d.ncon):
            g1, g2 = d.contact.geom1[i], d.contact.geom2[i]
            for pad, other in ((g1, g2), (g2, g1)):
                if pad in self._pad_geoms:
                    pads_touching.setdefault(m.geom_bodyid[other], set()).add(pad)
        for body, pads in pads_touching.items():
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, body)
            if len(pads) == 2 and name in self._welds:
                eq = self._welds[name]
                # relpose = pose of the object (body2) in the gripper's (body1) frame
                g_rot = geometry.to_rotation(d.xquat[self._gripper_body])
                m.eq_data[eq, 3:6] = g_rot.inv().apply(d.xpos[body] - d.xpos[self._gripper_body])
                m.eq_data[eq, 6:10] = geometry.from_rotation(g_rot.inv() * geometry.to_rotation(d.xquat[body]))
                d.eq_active[eq] = 1
                return


def weld_xml(object_body: str) -> str:
    """The (inactive) equality that a weld-on-close grasp of `object_body` switches on."""
    return (f'\n    <weld name="grasp_{object_body}" body1="gripper" body2="{object_body}" active="false" '
            f'solref="0.01 1"/>')


def _checked(trajectory: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    try:
        position = np.asarray(trajectory["position"], dtype=np.float64)
        quat = np.asarray(trajectory["orientation"], dtype=np.float64)
        command = np.asarray(trajectory["gripper"], dtype=np.float64)
    except KeyError as err:
        raise InputError(f"trajectory has no {err.args[0]!r} field") from None
    steps = len(position)
    if steps == 0 or position.shape != (steps, 3) or quat.shape != (steps, 4) or command.shape != (steps,):
        raise InputError(f"trajectory arrays must be (T,3), (T,4), (T,) with T >= 1; got "
                         f"{position.shape}, {quat.shape}, {command.shape}")
    if not (np.isfinite(position).all() and np.isfinite(quat).all() and np.isfinite(command).all()):
        raise InputError("trajectory holds non-finite numbers")
    low, high = sc.WORKSPACE
    outside = np.nonzero(((position < low) | (position > high)).any(axis=1))[0]
    if outside.size:
        k = int(outside[0])
        raise InputError(
            f"frame {k} (t = {k / sc.CONTROL_HZ:.2f} s) leaves the workspace: position "
            f"{np.round(position[k], 3).tolist()} m is outside {low.tolist()} .. {high.tolist()} m")
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    return position, quat, np.clip(command, 0.0, 1.0)


def run_episode(scene: Scene, trajectory: dict, judge):
    """Executes `trajectory` (see :meth:`Simulation.execute`) in a fresh simulation of
    `scene` and returns `judge`'s verdict on it."""
    sim = Simulation(scene)
    try:
        log, _ = sim.execute(trajectory)
    finally:
        sim.close()
    return judge(scene, log)
