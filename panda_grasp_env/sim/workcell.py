"""The workcell: one MuJoCo model and data, the robot, its controller and the blocks.

This is the physics layer the motion primitives and the Gymnasium env drive.
Its stepping (control rate, divergence detection, per-step observers) is ``physics``
(``sim.stepping``); the workcell adds motion helpers and the reset layouts.  World
frame, metres, radians throughout.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass

import mujoco
import numpy as np

from panda_grasp_env.control.controller import CartesianController, ControllerLimits, JointTargets
from panda_grasp_env.geometry import half_extent_along, yaw_quaternion
from panda_grasp_env.model.objects import ObjectShape, apply_shape
from panda_grasp_env.model.robot import HOME_POSITION, HOME_QPOS, HOME_YAW, PandaRobot
from panda_grasp_env.model.scene import (
    CONTACT_SOLIMP,
    CONTACT_SOLREF,
    HIDDEN_GROUP,
    OWN_FRICTION_PRIORITY,
    SceneConfig,
    build_spec,
    fixture_geoms,
    fixture_name,
)
from panda_grasp_env.sim.collateral import CollateralMonitor
from panda_grasp_env.sim.stepping import Physics

#: Reachable region for primitive targets: x, y, z bounds of the grasp site, metres.
WORKSPACE = np.array([[0.25, 0.75], [-0.35, 0.35], [0.0, 0.45]])
#: Region in which reset places blocks (inside WORKSPACE with a margin).
SPAWN_REGION = np.array([[0.35, 0.65], [-0.22, 0.22]])
#: Candidate block centres ``scattered_layout`` draws for one layout before it starts over.
LAYOUT_DRAWS = 2000
#: Where removed objects wait, out of every camera's view: a row on the floor behind the front camera.
PARKING_ORIGIN = np.array([2.5, 1.5, -0.75])
PARKING_SPACING = 0.3  # more than twice the largest object's bounding radius
#: Transit: the lowest point of the hand (fingertips, 15 mm below the grasp site) or of the object it carries
#: crosses this far above the tallest object, metres; and the grasp site never lower than TRANSIT_MIN_HEIGHT.
TRANSIT_CLEARANCE = 0.03
FINGERTIP_DEPTH = 0.015
TRANSIT_MIN_HEIGHT = 0.12
#: Reset IK solutions kept (least recently used dropped first).
TELEPORT_CACHE_SIZE = 64
_WORLD_GROUP = np.array([1, 0, 0, 0, 0, 0], dtype=np.uint8)  # ray casts see geom group 0 only: table and objects


@dataclass
class MoveOutcome:
    """How a Cartesian move of the grasp site ended: within tolerance of its goal or not, and how far off."""

    reached: bool
    #: Distance between the grasp site and the goal when the move ended, metres.
    error: float


#: MuJoCo geom types ``half_extent_along`` knows exactly, by its names.
_EXACT_TYPES = {
    int(mujoco.mjtGeom.mjGEOM_BOX): "box",
    int(mujoco.mjtGeom.mjGEOM_SPHERE): "sphere",
    int(mujoco.mjtGeom.mjGEOM_CAPSULE): "capsule",
    int(mujoco.mjtGeom.mjGEOM_CYLINDER): "cylinder",
}


def geom_extent_along(model: mujoco.MjModel, data: mujoco.MjData, geom: int, axis: np.ndarray) -> tuple[float, float]:
    """Lowest and highest coordinate of a geom along the world unit vector ``axis``, metres (exact for boxes,
    spheres, capsules, cylinders and meshes; bounding spheres otherwise)."""
    kind = _EXACT_TYPES.get(int(model.geom_type[geom]))
    if int(model.geom_type[geom]) == int(mujoco.mjtGeom.mjGEOM_MESH):
        mesh = model.geom_dataid[geom]
        start, count = model.mesh_vertadr[mesh], model.mesh_vertnum[mesh]
        heights = model.mesh_vert[start : start + count] @ (data.geom_xmat[geom].reshape(3, 3).T @ axis)
        centre = float(data.geom_xpos[geom] @ axis)
        return centre + float(heights.min()), centre + float(heights.max())
    if kind is None:
        half = float(model.geom_rbound[geom])
    else:
        half = half_extent_along(kind, model.geom_size[geom], data.geom_xmat[geom].reshape(3, 3), axis)
    centre = float(data.geom_xpos[geom] @ axis)
    return centre - half, centre + half


def body_extent_along(
    model: mujoco.MjModel, data: mujoco.MjData, body_id: int, axis: np.ndarray | Sequence[float]
) -> tuple[float, float]:
    """Lowest and highest coordinate of a body's collision geoms along the world unit vector ``axis``, metres
    (see ``geom_extent_along``)."""
    axis = np.asarray(axis, dtype=float)
    lowest, highest = np.inf, -np.inf
    start, count = model.body_geomadr[body_id], model.body_geomnum[body_id]
    for g in range(start, start + count):
        if model.geom_contype[g] or model.geom_conaffinity[g]:  # else visual only
            low, high = geom_extent_along(model, data, g, axis)
            lowest, highest = min(lowest, low), max(highest, high)
    return lowest, highest


def body_vertical_extent(model: mujoco.MjModel, data: mujoco.MjData, body_id: int) -> tuple[float, float]:
    """Lowest and highest world z of a body's collision geoms, metres (see ``body_extent_along``)."""
    return body_extent_along(model, data, body_id, (0.0, 0.0, 1.0))


def body_bottom_height(model: mujoco.MjModel, data: mujoco.MjData, body_id: int) -> float:
    """Lowest world z of a body's collision geoms, metres (see ``body_vertical_extent``)."""
    return body_vertical_extent(model, data, body_id)[0]


class Workcell:
    """A Panda, a table and free objects in one MuJoCo simulation.

    ``control_substeps`` physics steps make one control step (default 20 x 2 ms
    = 25 Hz, the rate of the env's low-level action modes): see ``physics``.
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
            )  # fmt: skip
            for b in self.object_ids
            for g in range(model.body_geomadr[b], model.body_geomadr[b] + model.body_geomnum[b])
        }
        self._dof_adr = {b: self.model.jnt_dofadr[self.model.body_jntadr[b]] for b in self.object_ids}
        #: Stepping: control steps, divergence checks, and the observers called after every step.
        self.physics: Physics[Workcell] = Physics(self, self.model, self.data, self.robot, self.object_ids,
                                                  control_substeps)  # fmt: skip
        self._teleport_solutions: dict[tuple, np.ndarray] = {}
        #: A task's fixtures (``Task.add_fixtures``): their collision geoms, and each one's fixture name (its
        #: body's, or its own for a geom of the world body).
        self.fixture_geom_ids = fixture_geoms(self.model)
        self.fixture_names = {int(g): fixture_name(self.model, g) for g in self.fixture_geom_ids}
        #: Transit and collateral accounting of the primitive running now (see ``collateral``).
        self.collateral = CollateralMonitor(self)
        self.physics.add_observer(self.collateral.on_control_step)  # first: later observers see it up to date
        self._scratch = mujoco.MjData(self.model)  # kinematics checks that must not touch the live state
        self.reset_robot()
        #: The fixtures' collision geoms standing on the table, as (x, y, reach, top) in metres: transit
        #: heights clear them as they clear objects (kept current by ``set_fixture_pose``/``set_fixture_size``).
        self.fixture_tops = self._fixture_tops()

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
        distance = mujoco.mj_ray(self.model, self.data, start, down, _WORLD_GROUP, 1, exclude_body, geom)
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
    def wait(self, seconds: float) -> None:
        """Keep the Cartesian controller's goal for ``seconds`` of simulated time."""
        for _ in range(max(1, int(round(seconds / self.physics.control_dt)))):
            self.physics.control_step(self.controller)

    # --- motion ------------------------------------------------------------
    def move_to(
        self,
        position: np.ndarray,
        yaw: float,
        speed: float | None = None,
        tolerance: float = 0.004,
        settle_timeout: float = 1.0,
        stop_when: Callable[[], bool] | None = None,
    ) -> MoveOutcome:
        """Drive the grasp site in a straight line to ``position`` with closing-axis heading ``yaw``.

        The reference moves at ``speed`` m/s (default and cap: the controller's limit).
        Returns once within ``tolerance`` metres of the goal at rest, after the
        settle timeout, or as soon as ``stop_when()`` is true -- or, in a primitive's
        work segment, as soon as the robot first touches a fixture the primitive was not
        aimed at (a protective stop; ``collateral``).
        """
        self.controller.set_goal(position, yaw, speed)
        goal = self.controller.goal_position
        travel_steps = int(np.ceil(self.controller.time_to_goal / self.physics.control_dt))
        settle_steps = int(np.ceil(settle_timeout / self.physics.control_dt))
        for i in range(travel_steps + 4 + settle_steps):
            self.physics.control_step(self.controller)
            if self.collateral.new_fixture_hit or (stop_when is not None and stop_when()):
                self.controller.stop()  # don't keep driving towards the goal after stopping
                break
            error = float(np.linalg.norm(self.robot.ee_position - goal))
            if i >= travel_steps and error < tolerance and np.abs(self.robot.joint_velocities).max() < 0.05:
                break
        error = float(np.linalg.norm(self.robot.ee_position - goal))
        return MoveOutcome(reached=error < tolerance, error=error)

    @contextmanager
    def one_heading(self, *points: np.ndarray) -> Iterator[None]:
        """Within the block every move turns the hand to the same half-turn branch of its goal heading: the one
        that puts joint 7 mid-range over the centre of ``points`` (world, metres), chosen once.  A primitive
        runs in one so that its hand does not turn half a revolution between goals whose own joint-7 windows
        differ (a push stroke across the line where they meet did)."""
        previous = self.controller.heading_window_at
        self.controller.heading_window_at = np.mean([np.asarray(p, dtype=float)[:2] for p in points], axis=0)
        try:
            yield
        finally:
            self.controller.heading_window_at = previous

    def _fixture_tops(self) -> list[tuple[float, float, float, float]]:
        model, data = self.model, self.data
        fixtures = []
        for g in self.fixture_geom_ids:
            top = geom_extent_along(model, data, g, np.array([0.0, 0.0, 1.0]))[1]
            if top > 1e-6:  # the table's top is the zero of heights: a fixture below it is out of the way
                fixtures.append((*map(float, data.geom_xpos[g][:2]), float(model.geom_rbound[g]), top))
        return fixtures

    # --- fixtures with state -------------------------------------------------
    def set_fixture_pose(
        self, name: str, position: Sequence[float], yaw: float = 0.0, quaternion: Sequence[float] | None = None
    ) -> None:
        """Move fixture ``name`` (a fixture body, or a fixture geom of the world body) to ``position`` (world,
        metres: the body's frame, or the geom's centre) turned by ``yaw`` about world z (radians), or to
        ``quaternion`` (w, x, y, z) if given.  For a task's ``reset``: the model changes, nothing is
        recompiled, and heights, ray casts, transit clearance and the motion planner's model follow."""
        position = np.asarray(position, dtype=float)
        if position.shape != (3,) or not np.all(np.isfinite(position)) or not np.isfinite(yaw):
            raise ValueError(
                f"fixture {name!r}: position must be 3 finite metres and yaw finite, got {position}, {yaw}"
            )
        orientation = yaw_quaternion(yaw) if quaternion is None else np.asarray(quaternion, dtype=float)
        if orientation.shape != (4,) or not np.isclose(np.linalg.norm(orientation), 1.0):
            raise ValueError(f"fixture {name!r}: quaternion must be a unit (w, x, y, z), got {quaternion!r}")
        body = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, name)
        if body > 0 and self.model.body_weldid[body] == 0 and body not in self.robot.body_ids:  # a static body
            self.model.body_pos[body], self.model.body_quat[body] = position, orientation
        else:
            geom = self._world_fixture_geom(name)
            self.model.geom_pos[geom], self.model.geom_quat[geom] = position, orientation
        self._fixtures_changed()

    def set_fixture_size(self, geom_name: str, size: Sequence[float]) -> None:
        """Resize a fixture's collision geom ``geom_name`` (box, sphere, capsule, cylinder or ellipsoid: MuJoCo's
        ``size`` of that type, metres) without recompiling; its bounding sphere and box follow.  For a task's
        ``reset``, like ``set_fixture_pose``."""
        geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, geom_name)
        if geom not in self.fixture_names:
            raise ValueError(f"unknown fixture geom {geom_name!r}; valid: {self._named_fixture_geoms()}")
        bounds = _primitive_bounds(int(self.model.geom_type[geom]), size)
        if bounds is None:
            raise ValueError(
                f"fixture geom {geom_name!r}: a size of 1-3 positive metres fitting its type is needed, and only "
                f"boxes, spheres, capsules, cylinders and ellipsoids resize without recompiling; got {size!r}"
            )
        self.model.geom_size[geom], self.model.geom_rbound[geom], self.model.geom_aabb[geom, 3:] = bounds
        self._fixtures_changed()

    def _world_fixture_geom(self, name: str) -> int:
        geom = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_GEOM, name)
        if geom not in self.fixture_names or self.model.geom_bodyid[geom] != 0:
            bodies = sorted({n for g, n in self.fixture_names.items() if self.model.geom_bodyid[g] != 0})
            world = [n for n in self._named_fixture_geoms() if self.model.geom(n).bodyid[0] == 0]
            raise ValueError(f"unknown fixture {name!r}; fixture bodies: {bodies}, fixture geoms of the world: {world}")
        return geom

    def _named_fixture_geoms(self) -> list[str]:
        names = (mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in self.fixture_geom_ids)
        return sorted(n for n in names if n)

    def _fixtures_changed(self) -> None:
        mujoco.mj_kinematics(self.model, self.data)  # geom poses (ray casts, heights) as the model now says
        self.fixture_tops = self._fixture_tops()

    def fixture_below(self, x: float, y: float) -> str | None:
        """The fixture whose surface is the first one straight below (x, y) once free objects are seen through
        (what a primitive at (x, y) works on or over), or None (the table or nothing)."""
        if not self.fixture_names:  # no fixture to find: no ray casts at every primitive's start
            return None
        geom = np.zeros(1, dtype=np.int32)
        start, down = np.array([x, y, 1.0]), np.array([0.0, 0.0, -1.0])
        exclude = -1
        for _ in range(len(self.object_ids) + 1):
            distance = mujoco.mj_ray(self.model, self.data, start, down, _WORLD_GROUP, 1, exclude, geom)
            if distance < 0:
                return None
            body = int(self.model.geom_bodyid[geom[0]])
            if body not in self._qpos_adr:
                return self.fixture_names.get(int(geom[0]))
            start, exclude = start + distance * down, body  # an object: look on below it
        return None

    def tallest_top(self, exclude: int | None = None, near: tuple[float, float, float] | None = None) -> float:
        """Highest top (world z, metres; 0 if none) of the objects on the table and the fixtures, leaving out
        ``exclude`` and, with ``near`` = (x, y, radius), everything whose footprint stays further than radius
        from (x, y)."""
        tops = [
            top
            for x, y, reach, top in self.fixture_tops
            if near is None or np.hypot(x - near[0], y - near[1]) < near[2] + reach
        ]
        tops.append(0.0)
        for b in map(int, self.object_ids):
            if b == exclude or self.is_parked(b):
                continue
            reach = self.model.geom_rbound[self.model.body_geomadr[b]]
            if near is not None and np.hypot(*(self.data.xpos[b][:2] - near[:2])) >= near[2] + reach:
                continue
            tops.append(body_vertical_extent(self.model, self.data, b)[1])
        return max(tops)

    def transit_height(self) -> float:
        """Grasp-site height (metres) at which the hand, and whatever it carries, clears every object on the
        table by ``TRANSIT_CLEARANCE``; at least ``TRANSIT_MIN_HEIGHT``, at most the workspace's top."""
        held = self.robot.body_between_fingers()
        hang = FINGERTIP_DEPTH
        if held is not None:
            hang = max(hang, self.robot.ee_position[2] - body_vertical_extent(self.model, self.data, held)[0])
        height = self.tallest_top(exclude=held) + TRANSIT_CLEARANCE + hang
        return float(min(max(height, TRANSIT_MIN_HEIGHT), WORKSPACE[2, 1]))

    def clear_height_near(self, x: float, y: float, radius: float = 0.12) -> float:
        """Grasp-site height (metres) at which the empty hand over (x, y) clears, by ``TRANSIT_CLEARANCE``, every
        object whose footprint comes within ``radius`` of (x, y) (the hand's half-span)."""
        return self.tallest_top(near=(x, y, radius)) + TRANSIT_CLEARANCE + FINGERTIP_DEPTH

    def rise(self, height: float | None = None) -> None:
        """Straight up to ``height`` (default: the transit height), if the grasp site is lower."""
        height = self.transit_height() if height is None else height
        position = self.robot.ee_position
        if position[2] < height - 0.005:
            self.move_to(np.array([*position[:2], height]), self.robot.ee_yaw, settle_timeout=0.2, tolerance=0.02)

    def transit(self, x: float, y: float, yaw: float) -> MoveOutcome:
        """Travel to (x, y) at the transit height, the hand turned to ``yaw``: straight up first, then in a
        straight line, which never dips below the transit height since it starts at or above it (home is
        higher than any transit height)."""
        height = self.transit_height()
        self.rise(height)
        return self.move_to(np.array([x, y, height]), yaw, tolerance=0.01)

    def _joint_line_stays_above(self, goal: np.ndarray, height: float, samples: int = 12) -> bool:
        """Whether the grasp site stays at least ``height`` (metres) high all along the straight joint-space
        line from the arm's current joints to ``goal`` (the hand is the robot's lowest part there)."""
        scratch = self._scratch
        scratch.qpos[:] = self.data.qpos
        start = self.robot.joint_positions
        for fraction in np.linspace(0.0, 1.0, samples + 1)[1:]:
            scratch.qpos[self.robot.arm_qpos_idx] = start + fraction * (goal - start)
            mujoco.mj_kinematics(self.model, scratch)
            if scratch.site_xpos[self.robot.site_id][2] < height:
                return False
        return True

    def move_home(self, joint_speed: float = 1.2) -> None:
        """Back to the home configuration without sweeping through the scene: straight up to the transit
        height, then a joint-space move at ``joint_speed`` rad/s onto the home joint angles if the hand stays
        above the transit height all along it, else across to the home position in a straight line first
        (home is higher than any transit); settle."""
        height = self.transit_height()
        self.rise(height)
        if not self._joint_line_stays_above(HOME_QPOS, height - 0.01):
            self.move_to(HOME_POSITION, HOME_YAW, settle_timeout=0.2, tolerance=0.03)
        start = self.robot.joint_positions
        n = max(1, int(np.ceil(np.abs(HOME_QPOS - start).max() / (joint_speed * self.physics.control_dt))))
        for fraction in np.linspace(0.0, 1.0, n + 1)[1:]:
            self.physics.control_step(JointTargets(start + fraction * (HOME_QPOS - start)))
        for _ in range(int(0.6 / self.physics.control_dt)):
            if np.abs(self.robot.joint_positions - HOME_QPOS).max() < 0.01:
                break
            self.physics.control_step(None)  # the servos keep the home targets
        self.controller.sync(self.robot.joint_positions)

    def teleport_hand(self, position: np.ndarray, yaw: float, max_iterations: int = 300) -> float:
        """Put the arm, at rest, in the configuration that holds the grasp site at ``position`` with heading ``yaw``.

        Solves the IK on its own (no physics time passes); for resets.  Returns
        the remaining position error, metres.
        """
        # The IK is deterministic, so each (start, goal) is solved once; goals are rounded to 0.1 mm
        # first, so the answer never depends on which nearby goal came first.
        position = np.round(np.asarray(position, dtype=float), 4)
        yaw = round(float(yaw), 4)
        start = self.robot.joint_positions
        key = (*position, yaw, *start)
        solution = self._teleport_solutions.pop(key, None)
        if solution is None:
            self.controller.sync(start)
            self.controller.set_goal(position, yaw)
            for _ in range(max_iterations):
                self.controller.step(self.physics.control_dt)
                if self.controller.converged:
                    break
            solution = self.controller.commanded_qpos
            if len(self._teleport_solutions) >= TELEPORT_CACHE_SIZE:
                del self._teleport_solutions[next(iter(self._teleport_solutions))]  # least recently used
        self._teleport_solutions[key] = solution
        self.data.qpos[self.robot.arm_qpos_idx] = solution
        self.data.qvel[self.robot.arm_qvel_idx] = 0.0
        self.robot.command_joints(solution)
        mujoco.mj_forward(self.model, self.data)
        self.controller.sync(self.robot.joint_positions)
        return float(np.linalg.norm(self.robot.ee_position - position))

    def actuate_gripper(self, close: bool, timeout: float = 0.8) -> None:
        """Open or close the gripper and wait until the fingers stop (or ``timeout`` seconds)."""
        if close:
            self.robot.close_gripper()
        else:
            self.robot.open_gripper()
        still = 0
        for _ in range(int(np.ceil(timeout / self.physics.control_dt))):
            self.physics.control_step(self.controller)
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


def _primitive_bounds(geom_type: int, size: Sequence[float]) -> tuple[np.ndarray, float, np.ndarray] | None:
    """MuJoCo's (size, bounding-sphere radius, local bounding-box half sizes) of a box, sphere, capsule,
    cylinder or ellipsoid of ``size`` (metres: as many as the type uses), or None for another type or a bad
    size."""
    values = np.asarray(size, dtype=float).ravel()
    used = {int(mujoco.mjtGeom.mjGEOM_BOX): 3, int(mujoco.mjtGeom.mjGEOM_ELLIPSOID): 3,
            int(mujoco.mjtGeom.mjGEOM_SPHERE): 1, int(mujoco.mjtGeom.mjGEOM_CAPSULE): 2,
            int(mujoco.mjtGeom.mjGEOM_CYLINDER): 2}.get(geom_type)  # fmt: skip
    if used is None or values.size != used or not np.all(np.isfinite(values) & (values > 0)):
        return None
    full = np.zeros(3)
    full[:used] = values
    if used == 3:
        return full, float(np.linalg.norm(full) if geom_type == mujoco.mjtGeom.mjGEOM_BOX else full.max()), full
    radius = full[0]
    if used == 1:
        return full, radius, np.full(3, radius)
    half = full[1]
    if geom_type == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return full, radius + half, np.array([radius, radius, radius + half])
    return full, float(np.hypot(radius, half)), np.array([radius, radius, half])


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
