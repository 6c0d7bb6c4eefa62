"""The workcell: one MuJoCo model and data, the robot, its controller, the free objects and a task's fixtures.

This is the physics layer the motion primitives and the Gymnasium env drive, and the one object they talk to.
It answers scene queries (where objects are, what touches what, what surface is below a point), sets objects
(poses, shapes, friction), holds the hand still while time passes, and resets the scene.  Its parts do the
rest: ``physics`` steps the simulation (control steps, divergence checks, per-step observers;
``sim.stepping``), ``motion`` moves the grasp site (``sim.motion``), ``fixtures`` are a task's fixtures
(``sim.fixtures``), ``collateral`` watches what a primitive disturbs (``sim.collateral``).  World frame,
metres, radians throughout.
"""

from __future__ import annotations

import mujoco
import numpy as np

from panda_grasp_env.control.controller import CartesianController, ControllerLimits
from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.model.objects import ObjectShape, apply_shape
from panda_grasp_env.model.robot import PandaRobot
from panda_grasp_env.model.scene import (
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    HIDDEN_GROUP,
    OWN_FRICTION_PRIORITY,
    SceneConfig,
    build_spec,
)
from panda_grasp_env.sim.collateral import CollateralMonitor
from panda_grasp_env.sim.fixtures import WORLD_GROUP, Fixtures
from panda_grasp_env.sim.motion import Motion
from panda_grasp_env.sim.stepping import Physics

#: The geom fields ``objects.apply_shape`` writes.  A slot's geoms get their compiled values back before each
#: new shape, so that they are a function of that shape alone: a mesh of 4 parts after one of 12 left the 8
#: hidden parts holding the old mesh, which changed the collision tree, the order of contacts and so the
#: settling -- an episode's outcome then hung on the objects before it.
SHAPE_GEOM_FIELDS = (
    "geom_type",
    "geom_dataid",
    "geom_pos",
    "geom_quat",
    "geom_size",
    "geom_rbound",
    "geom_aabb",
    "geom_rgba",
    "geom_contype",
    "geom_conaffinity",
    "geom_group",
)
#: Region in which reset places blocks (inside ``motion.WORKSPACE`` with a margin).
SPAWN_REGION = np.array([[0.35, 0.65], [-0.22, 0.22]])
#: Candidate block centres ``scattered_layout`` draws for one layout before it starts over.
LAYOUT_DRAWS = 2000
#: Where removed objects wait, out of every camera's view: a row on the floor behind the front camera.
PARKING_ORIGIN = np.array([2.5, 1.5, -0.75])
PARKING_SPACING = 0.3  # more than twice the largest object's bounding radius


class Workcell:
    """A Panda, a table and free objects in one MuJoCo simulation.

    ``control_substeps`` physics steps make one control step (default 20 x 2 ms
    = 25 Hz, the rate of the env's low-level action modes): see ``physics``.
    ``limits`` bound the Cartesian controller's speeds.
    """

    def __init__(
        self,
        config: SceneConfig | None = None,
        control_substeps: int = 20,
        limits: ControllerLimits | None = None,
    ) -> None:
        self.config = config or SceneConfig()
        self.spec = build_spec(self.config)
        self.model = self.spec.compile()
        hidden = self.model.geom_group == HIDDEN_GROUP  # object-slot geoms no shape uses yet: no contacts
        self.model.geom_contype[hidden] = self.model.geom_conaffinity[hidden] = 0
        self.data = mujoco.MjData(self.model)
        self.robot = PandaRobot(self.model, self.data)
        self.controller = CartesianController(self.config, limits)
        self.block_names = self.config.block_names
        self.block_ids = np.array([self.model.body(n).id for n in self.block_names], dtype=int)
        #: Every free body: the coloured blocks, then the variable-shape object slots.
        self.object_names = self.block_names + self.config.object_names
        self.object_ids = np.array([self.model.body(n).id for n in self.object_names], dtype=int)
        self._qpos_adr = {b: self.model.jnt_qposadr[self.model.body_jntadr[b]] for b in self.object_ids}
        #: Free object geom -> its compiled (friction, solref, solimp, priority), restored for objects without
        #: their own friction.
        model = self.model
        self._slot_contacts = {
            int(g): (
                model.geom_friction[g].copy(),
                model.geom_solref[g].copy(),
                model.geom_solimp[g].copy(),
                int(model.geom_priority[g]),
            )
            for b in self.object_ids
            for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b])
        }
        self._compiled_geoms = {name: getattr(model, name).copy() for name in SHAPE_GEOM_FIELDS}
        self._dof_adr = {b: self.model.jnt_dofadr[self.model.body_jntadr[b]] for b in self.object_ids}
        #: Stepping: control steps, divergence checks, and the observers called after every step.
        self.physics: Physics[Workcell] = Physics(
            self, self.model, self.data, self.robot, self.object_ids, control_substeps
        )
        self.reset_robot()  # home: the kinematics the fixtures' heights are read from
        #: A task's fixtures (``Task.add_fixtures``): their geoms, heights, moves and resizes.
        self.fixtures = Fixtures(self.model, self.data, self.robot.body_ids, self.object_ids)
        #: Transit and collateral accounting of the primitive running now (see ``collateral``).
        self.collateral = CollateralMonitor(self)
        self.physics.add_observer(self.collateral.on_control_step)  # first: later observers see it up to date
        #: Moves of the grasp site (Cartesian, transit, home) and teleports of the hand for resets.
        self.motion = Motion(self)

    # --- state -------------------------------------------------------------
    @property
    def sim_time(self) -> float:
        """Simulated seconds since the last reset."""
        return float(self.data.time)

    def block_positions(self) -> np.ndarray:
        """Block centres (n, 3), world frame, metres."""
        return self.data.xpos[self.block_ids].copy()

    def object_positions(self) -> np.ndarray:
        """Centres (n, 3) of all free bodies (blocks, then object slots), world frame, metres."""
        return self.data.xpos[self.object_ids].copy()

    def is_parked(self, body_id: int) -> bool:
        """Whether a free body is off the table (parked, fallen or pushed off)."""
        return bool(self.data.xpos[body_id][2] < -0.1)

    def block_yaws(self) -> np.ndarray:
        """Heading of each block's x axis about world z, radians."""
        x_axes = self.data.xmat[self.block_ids].reshape(-1, 3, 3)[:, :, 0]
        return np.arctan2(x_axes[:, 1], x_axes[:, 0])

    def name_of(self, body_id: int | None) -> str | None:
        return None if body_id is None else mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_BODY, body_id)

    def surface_below(self, x: float, y: float, exclude_body: int = -1) -> tuple[float, int]:
        """(height of the highest table or object surface straight below (x, y), metres, 0 = table top;
        the body id of that object, -1 for the table or nothing).  The robot is not seen."""
        geom = np.zeros(1, dtype=np.int32)
        start, down = np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0])
        distance = mujoco.mj_ray(self.model, self.data, start, down, WORLD_GROUP, 1, exclude_body, geom)
        if distance < 0:
            return 0.0, -1
        body = int(self.model.geom_bodyid[geom[0]])
        return max(0.0, 1.0 - distance), (body if body in self._qpos_adr else -1)

    def bodies_touching(self, body_id: int) -> set[int]:
        """Ids of the bodies in contact with a body (as of the last forward pass or step)."""
        geom_body = self.model.geom_bodyid
        touching = set()
        for contact in self.data.contact[: self.data.ncon]:
            b1, b2 = int(geom_body[contact.geom1]), int(geom_body[contact.geom2])
            if body_id in (b1, b2):
                touching.add(b2 if b1 == body_id else b1)
        return touching

    def touches_world(self, body_id: int) -> bool:
        """Whether a body is in contact with anything other than the robot."""
        return any(other not in self.robot.body_ids for other in self.bodies_touching(body_id))

    def touches_robot(self, body_id: int) -> bool:
        """Whether a body is in contact with the robot."""
        return any(other in self.robot.body_ids for other in self.bodies_touching(body_id))

    # --- holding still ------------------------------------------------------
    def wait(self, seconds: float, keep_joint_targets: bool = False) -> None:
        """Keep the Cartesian controller's goal for ``seconds`` of simulated time; ``keep_joint_targets``: keep
        the arm's joint targets instead (a hand not pointing down, which the controller would turn)."""
        controller = None if keep_joint_targets else self.controller
        for _ in range(max(1, int(round(seconds / self.physics.control_dt)))):
            self.physics.control_step(controller)

    def actuate_gripper(self, close: bool, timeout: float = 0.8, keep_joint_targets: bool = False) -> None:
        """Open or close the gripper and wait as ``wait`` does until the fingers stop (or ``timeout`` seconds)."""
        if close:
            self.robot.close_gripper()
        else:
            self.robot.open_gripper()
        controller = None if keep_joint_targets else self.controller
        still = 0
        for _ in range(int(np.ceil(timeout / self.physics.control_dt))):
            self.physics.control_step(controller)
            still = still + 1 if self.robot.finger_speed < 2e-3 else 0
            if still >= 3:
                break

    # --- objects -----------------------------------------------------------
    def set_body_pose(self, body_id: int, position: np.ndarray, quaternion: np.ndarray | None = None) -> None:
        """Teleport a free body to ``position`` (world, metres) with ``quaternion`` (w, x, y, z), at rest."""
        adr, dof = self._qpos_adr[body_id], self._dof_adr[body_id]
        self.data.qpos[adr : adr + 3] = position
        self.data.qpos[adr + 3 : adr + 7] = [1.0, 0.0, 0.0, 0.0] if quaternion is None else quaternion
        self.data.qvel[dof : dof + 6] = 0.0

    def park(self, body_id: int) -> None:
        """Set a free body aside: upright on the floor beside the table, out of view and out of the way, at rest
        (a body dropped there would still be falling when the next primitive's collateral watch begins)."""
        slot = int(np.flatnonzero(self.object_ids == body_id)[0])
        lift = self.model.geom_aabb[self.model.body_geomadr[body_id], 5]  # half height in the body frame
        self.set_body_pose(body_id, PARKING_ORIGIN + [slot * PARKING_SPACING, 0.0, lift])
        mujoco.mj_kinematics(self.model, self.data)  # positions read right after parking are current

    def set_object_shapes(self, shapes: dict[int, ObjectShape]) -> None:
        """Give object slots (body id -> shape) new shapes; the model's derived constants are recomputed."""
        for body_id, shape in shapes.items():
            geoms = slice(
                self.model.body_geomadr[body_id], self.model.body_geomadr[body_id] + self.model.body_geomnum[body_id]
            )
            for name, compiled in self._compiled_geoms.items():
                getattr(self.model, name)[geoms] = compiled[geoms]
            apply_shape(self.model, body_id, shape)
            self.set_object_friction(body_id, shape.friction)
        self.refresh_constants()

    def set_object_friction(self, body_id: int, friction: float | None) -> None:
        """Make ``friction`` the sliding coefficient in effect between a free object and the table, the finger
        pads and fixtures; None restores the compiled one (a contact then takes the larger of its pair's).

        An object with its own friction gets the highest geom priority, so that its coefficient is the one
        used, and the pads' contact softness (``CONTACT_SOLREF``), which the priority also decides."""
        model = self.model
        start = int(model.body_geomadr[body_id])
        for geom in range(start, start + int(model.body_geomnum[body_id])):  # a mesh slot's part geoms too
            compiled_friction, solref, solimp, priority = self._slot_contacts[geom]
            sliding = compiled_friction
            if friction is not None:
                sliding = np.array([friction, *compiled_friction[1:]])
                solref, solimp, priority = CONTACT_SOLREF, CONTACT_SOLIMP, OWN_FRICTION_PRIORITY
            model.geom_friction[geom], model.geom_solref[geom], model.geom_solimp[geom] = sliding, solref, solimp
            model.geom_priority[geom] = priority

    def refresh_constants(self) -> None:
        """Recompute the model's derived constants after masses or inertias changed, keeping the state."""
        # mj_setConst uses the data as scratch space and leaves it at qpos0.
        state = self.data.qpos.copy(), self.data.qvel.copy(), self.data.ctrl.copy()
        mujoco.mj_setConst(self.model, self.data)
        self.data.qpos[:], self.data.qvel[:], self.data.ctrl[:] = state
        mujoco.mj_forward(self.model, self.data)

    # --- reset -------------------------------------------------------------
    def reset_robot(self) -> None:
        """Robot at home, at rest, gripper open; controller state cleared."""
        self.robot.set_home()
        mujoco.mj_forward(self.model, self.data)
        self.controller.sync(self.robot.joint_positions)

    def clear(self) -> None:
        """Fresh physics state: every free body parked, robot at home, time zero."""
        mujoco.mj_resetData(self.model, self.data)  # also clears warm-starts and warnings
        for body_id in self.object_ids:
            self.park(body_id)
        self.reset_robot()
        self.physics.steps = 0

    def settle(self, seconds: float) -> None:
        """Let the scene come to rest for ``seconds``, then restart the clock (time and step count at zero)."""
        if seconds > 0:
            self.wait(seconds)
        self.data.time = 0.0
        self.physics.steps = 0

    def place_blocks(self, rng: np.random.Generator, layout: str = "scattered") -> None:
        """Put the coloured blocks on the table in a ``"scattered"`` or ``"tower"`` layout drawn from ``rng``."""
        if layout == "scattered":
            positions, yaws = scattered_layout(rng, len(self.block_ids), self.config.block_size)
        elif layout == "tower":
            positions, yaws = tower_layout(rng, len(self.block_ids), self.config.block_size)
        else:
            raise ValueError(f"unknown layout {layout!r}; valid: ['scattered', 'tower']")
        self.set_block_poses(positions, yaws)

    def set_block_poses(self, positions: np.ndarray, yaws: np.ndarray) -> None:
        """Put block i's centre at ``positions[i]`` (world, metres) turned ``yaws[i]`` radians about z, at rest."""
        for body_id, position, yaw in zip(self.block_ids, positions, yaws):
            self.set_body_pose(body_id, position, yaw_quaternion(yaw))
        mujoco.mj_forward(self.model, self.data)

    def reset(self, rng: np.random.Generator, layout: str = "scattered", settle: float = 0.3) -> None:
        """Reset physics and robot and lay the blocks out (see ``place_blocks``); all randomness from ``rng``.

        ``layout``: ``"scattered"`` (blocks apart at random positions and yaws in
        the spawn region) or ``"tower"`` (all blocks stacked, in random colour
        order, at a random spot and yaw).
        """
        self.clear()
        self.place_blocks(rng, layout)
        self.settle(settle)


def scattered_layout(
    rng: np.random.Generator, n_blocks: int, block_size: float, region: np.ndarray = SPAWN_REGION
) -> tuple[np.ndarray, np.ndarray]:
    """Non-overlapping block centres (n, 3) and yaws (n,) resting on the table: each centre drawn uniformly in
    ``region`` until it lies ``block_size * sqrt(2) + 0.03`` m or more from the others'; a layout still
    incomplete after ``LAYOUT_DRAWS`` centres starts over (five-centimetre blocks in ``SPAWN_REGION`` took at most
    18 centres for four blocks and 195 for eight, over 3,000 seeds)."""
    min_distance = block_size * np.sqrt(2) + 0.03  # diagonal plus room for a finger
    positions: list[np.ndarray] = []
    draws = 0
    while len(positions) < n_blocks:
        if draws == LAYOUT_DRAWS:  # the blocks drawn so far leave no room for the rest
            positions, draws = [], 0
        draws += 1
        candidate = np.array([rng.uniform(*region[0]), rng.uniform(*region[1]), block_size / 2])
        if all(np.linalg.norm(candidate[:2] - p[:2]) >= min_distance for p in positions):
            positions.append(candidate)
    return np.array(positions), rng.uniform(-np.pi / 4, np.pi / 4, n_blocks)


def tower_layout(
    rng: np.random.Generator, n_blocks: int, block_size: float, region: np.ndarray = SPAWN_REGION
) -> tuple[np.ndarray, np.ndarray]:
    """A tower of all blocks in random order at a random spot and yaw: centres (n, 3) and yaws (n,)."""
    x, y = rng.uniform(*region[0]), rng.uniform(*region[1])
    yaw = rng.uniform(-np.pi / 4, np.pi / 4)
    order = rng.permutation(n_blocks)
    positions = np.zeros((n_blocks, 3))
    for level, block in enumerate(order):
        # A 0.1 mm gap per level avoids initial interpenetration; blocks settle onto each other.
        positions[block] = [x, y, block_size / 2 + level * (block_size + 1e-4)]
    return positions, np.full(n_blocks, yaw)
