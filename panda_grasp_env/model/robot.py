"""The Panda arm and hand: state, gripper and joint commands on a live ``MjData``.

Joint angles are radians; positions metres in the world frame; the end-effector
is the ``grasp_site`` between the finger pads, whose z axis is the approach
direction and whose x axis is the closing axis.
"""

from __future__ import annotations

import mujoco
import numpy as np

from panda_grasp_env.model.scene import (
    ARM_ACTUATORS,
    ARM_JOINTS,
    FINGER_ACTUATORS,
    FINGER_BODIES,
    FINGER_JOINTS,
    GRASP_SITE,
    MAX_FINGER_GAP,
    PAD_PROTRUSION,
)

#: Home configuration: grasp site at (0.2, 0, 0.45) m, pulled back so the overhead
#: camera sees the whole workspace; gripper pointing down, closing axis along world y.
HOME_QPOS = np.array([0.0, -1.1266, 0.0, -2.5112, 0.0, -0.1856, 0.0])
HOME_POSITION = np.array([0.2, 0.0, 0.45])
HOME_YAW = -np.pi / 2
#: Finger joint command when open / closed (each finger slides 0-0.04 m).
FINGER_OPEN = 0.04
FINGER_CLOSED = 0.0
#: The fingertips reach this far (metres) below the grasp site.
FINGERTIP_DEPTH = 0.015
#: The closed hand seen from its grasp site, metres (the Panda model's collision geometry; a test measures it):
#: the hand body's bottom above the site, its half-length along the closing axis and half-width across it;
#: the fingers' half-width along the closing axis at their widest (their base, up to 8.3 cm above the site) and
#: over their lowest 3 cm (what touches a pushed piece); and their half-thickness across the closing axis
#: below the base.
HAND_BODY_ABOVE_SITE, HAND_BODY_HALF_LENGTH, HAND_BODY_HALF_WIDTH = 0.072, 0.105, 0.044
FINGER_HALF_WIDTH = 0.027
FINGER_TIP_HALF_WIDTH = 0.021
FINGER_HALF_THICKNESS = 0.020


def fast_index(indices: np.ndarray) -> slice | np.ndarray:
    """``indices`` as a slice when they are consecutive (a view, and cheaper than fancy indexing in the
    step loop), else unchanged."""
    if len(indices) and np.array_equal(indices, np.arange(indices[0], indices[0] + len(indices))):
        return slice(int(indices[0]), int(indices[0]) + len(indices))
    return indices


class PandaRobot:
    """Typed view of the Panda inside a workcell ``MjModel``/``MjData`` pair."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        self.model = model
        self.data = data
        self.arm_qpos_idx = np.array([model.jnt_qposadr[model.joint(n).id] for n in ARM_JOINTS])
        self.arm_qvel_idx = np.array([model.jnt_dofadr[model.joint(n).id] for n in ARM_JOINTS])
        self.finger_qpos_idx = np.array([model.jnt_qposadr[model.joint(n).id] for n in FINGER_JOINTS])
        self.finger_qvel_idx = np.array([model.jnt_dofadr[model.joint(n).id] for n in FINGER_JOINTS])
        self._finger_qpos = tuple(int(i) for i in self.finger_qpos_idx)
        self.arm_ctrl_idx = np.array([model.actuator(n).id for n in ARM_ACTUATORS])
        self.finger_ctrl_idx = np.array([model.actuator(n).id for n in FINGER_ACTUATORS])
        self.site_id = model.site(GRASP_SITE).id
        self.body_ids = {
            i for i in range(model.nbody) if mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i).startswith("panda0_")
        }
        #: (left, right): each finger's body, which carries its pad.
        self.finger_bodies = tuple(model.body(n).id for n in FINGER_BODIES)
        self.arm_lower = model.jnt_range[[model.joint(n).id for n in ARM_JOINTS], 0].copy()
        self.arm_upper = model.jnt_range[[model.joint(n).id for n in ARM_JOINTS], 1].copy()

    # --- state -------------------------------------------------------------
    @property
    def joint_positions(self) -> np.ndarray:
        """Arm joint angles (7,), radians."""
        return self.data.qpos[self.arm_qpos_idx].copy()

    @property
    def joint_velocities(self) -> np.ndarray:
        """Arm joint velocities (7,), rad/s."""
        return self.data.qvel[self.arm_qvel_idx].copy()

    @property
    def ee_position(self) -> np.ndarray:
        """Grasp-site position (3,) in the world frame, metres."""
        return self.data.site_xpos[self.site_id].copy()

    @property
    def ee_rotation(self) -> np.ndarray:
        """Grasp-site orientation (3, 3) in the world frame."""
        return self.data.site_xmat[self.site_id].reshape(3, 3).copy()

    @property
    def ee_yaw(self) -> float:
        """Heading of the closing axis about world z, radians."""
        x_axis = self.ee_rotation[:, 0]
        return float(np.arctan2(x_axis[1], x_axis[0]))

    @property
    def finger_gap(self) -> float:
        """Distance between the two finger pads, metres (0 when closed on nothing)."""
        qpos, (left, right) = self.data.qpos, self._finger_qpos
        gap = float(qpos[left]) + float(qpos[right]) - 2 * PAD_PROTRUSION
        return min(max(gap, 0.0), MAX_FINGER_GAP)

    @property
    def finger_speed(self) -> float:
        """Largest finger joint speed, m/s."""
        return float(np.abs(self.data.qvel[self.finger_qvel_idx]).max())

    # --- commands ----------------------------------------------------------
    def command_joints(self, qpos: np.ndarray) -> None:
        """Set the arm's position-servo targets (7,), clipped to the joint limits."""
        self.data.ctrl[self.arm_ctrl_idx] = np.minimum(np.maximum(qpos, self.arm_lower), self.arm_upper)

    def open_gripper(self) -> None:
        self.data.ctrl[self.finger_ctrl_idx] = FINGER_OPEN

    def command_fingers(self, opening: float) -> None:
        """Finger position target, metres per finger (0 closed .. ``FINGER_OPEN``), force-limited."""
        self.data.ctrl[self.finger_ctrl_idx] = min(max(float(opening), FINGER_CLOSED), FINGER_OPEN)

    def teleport_fingers(self, opening: float) -> None:
        """Put both fingers at ``opening`` (metres per finger) at once, commanded to stay there (resets only:
        no physics time passes; the caller's next forward pass or step sees them there)."""
        self.command_fingers(opening)
        self.data.qpos[self.finger_qpos_idx] = self.data.ctrl[self.finger_ctrl_idx[0]]
        self.data.qvel[self.finger_qvel_idx] = 0.0

    def close_gripper(self) -> None:
        """Close both fingers; each squeezes with at most the scene's ``gripper_force``."""
        self.data.ctrl[self.finger_ctrl_idx] = FINGER_CLOSED

    @property
    def gripper_closing(self) -> bool:
        return bool(self.data.ctrl[self.finger_ctrl_idx[0]] < FINGER_OPEN / 2)

    def set_home(self) -> None:
        """Teleport to the home configuration at rest with the gripper open (for resets)."""
        self.data.qpos[self.arm_qpos_idx] = HOME_QPOS
        self.data.qvel[self.arm_qvel_idx] = 0.0
        self.teleport_fingers(FINGER_OPEN)
        self.command_joints(HOME_QPOS)

    def bodies_between_fingers(self) -> set[int]:
        """Free bodies that both fingers touch: the ones held.

        A finger may touch with its pad or its capsules: an object that slips up past the pads is still held (a
        pads-only test read it as dropped, and the arm let it go wherever it then was).  The table, fixtures and
        the bin (bodies without degrees of freedom) are never held.  Contacts count whatever their direction:
        closed fingertips resting on an object's top count too, but requiring a contact across the closing axis
        (within 60 degrees) also rejected grips that would have lifted the block (see docs/internals.md)."""
        touching: dict[int, set[int]] = {finger: set() for finger in self.finger_bodies}
        geom_body = self.model.geom_bodyid
        for contact in self.data.contact[: self.data.ncon]:
            for mine, other in ((contact.geom1, contact.geom2), (contact.geom2, contact.geom1)):
                finger, body = int(geom_body[mine]), int(geom_body[other])
                if finger in touching and body not in self.body_ids and self.model.body_dofnum[body] > 0:
                    touching[finger].add(body)
        left, right = self.finger_bodies
        return touching[left] & touching[right]

    def body_between_fingers(self) -> int | None:
        """The held body (``bodies_between_fingers``) nearest the grasp site -- the one grasped, not one lying
        on it and caught between the fingers above -- or None."""
        held = self.bodies_between_fingers()
        site = self.data.site_xpos[self.site_id]
        return min(held, key=lambda body: np.linalg.norm(self.data.xpos[body] - site)) if held else None
