"""Collision-free joint-space motion planning with OMPL, checked by MuJoCo's own collision detection.

The planning model is the simulation's workcell with the robot's links allowed
to collide with each other (the simulation leaves link-link contacts off), plus
any extra box obstacles.  A configuration is valid when no robot geom touches
anything -- the world, an object, an obstacle or another link (MuJoCo already
skips a link and its parent).  Objects, and the fixtures' poses and sizes (which
a task may change per episode), are copied from the live simulation with
``sync_objects`` and ``sync_fixtures``.  Paths are simplified with OMPL's shortcutting.

Joint angles in radians; obstacle sizes are half-extents in metres, world frame.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import mujoco
import numpy as np
from ompl import base as ob
from ompl import geometric as og
from ompl import util as ou

from panda_grasp_env.model.robot import FINGER_OPEN, PandaRobot
from panda_grasp_env.model.scene import ARM_JOINTS, SceneConfig, build_spec, fixture_elements

#: The OMPL planners this module can run, by name.
PLANNERS = {
    "RRTConnect": og.RRTConnect,
    "RRT": og.RRT,
    "PRM": og.PRM,
    "KPIECE1": og.KPIECE1,
    "BKPIECE1": og.BKPIECE1,
    "LBKPIECE1": og.LBKPIECE1,
    "FMT": og.FMT,
    "RRTstar": og.RRTstar,
    "BITstar": og.BITstar,
    "AORRTC": og.AORRTC,
}
ou.setLogLevel(ou.LogLevel.LOG_NONE)


@dataclass(frozen=True)
class Box:
    """A static box obstacle: centre and half-extents, metres."""

    centre: tuple[float, float, float]
    half_size: tuple[float, float, float]


@dataclass(frozen=True)
class PlanResult:
    """A planning query's answer: whether a path was found, the path, its length, the planning time (seconds)
    and the OMPL planner that ran."""

    success: bool
    #: Waypoints (N, 7) in joint space, start to goal (empty without a solution).
    path: np.ndarray
    #: Joint-space length of the simplified path, radians.
    length: float
    seconds: float
    planner: str


class CollisionChecker:
    """Whether an arm configuration is collision-free in a planning model: no robot geom touches anything (the
    world, an object, an obstacle or another link)."""

    def __init__(self, model: mujoco.MjModel, data: mujoco.MjData, robot: PandaRobot) -> None:
        self.model, self.data, self.arm_qpos_idx = model, data, robot.arm_qpos_idx
        self._robot_geom = np.isin(model.geom_bodyid, sorted(robot.body_ids))
        #: Calls so far.
        self.checks = 0

    def __call__(self, arm_qpos: np.ndarray) -> bool:
        """True when nothing touches the robot at ``arm_qpos`` (radians, (7,))."""
        self.checks += 1
        self.data.qpos[self.arm_qpos_idx] = arm_qpos
        mujoco.mj_kinematics(self.model, self.data)
        mujoco.mj_collision(self.model, self.data)
        if self.data.ncon == 0:
            return True
        geoms = self.data.contact.geom[: self.data.ncon]
        return not self._robot_geom[geoms].any()


class MotionPlanner:
    """Plans arm motions between joint configurations around the workcell's contents."""

    def __init__(
        self,
        scene_config: SceneConfig | None = None,
        obstacles: tuple[Box, ...] = (),
        planner: str = "RRTConnect",
        resolution: float = 0.005,
        seed: int = 0,
    ) -> None:
        if planner not in PLANNERS:
            raise ValueError(f"unknown planner {planner!r}; valid: {sorted(PLANNERS)}")
        spec = build_spec(scene_config or SceneConfig(), self_collision=True)
        for index, box in enumerate(obstacles):
            geom = spec.worldbody.add_geom()
            geom.name = f"obstacle_{index}"
            geom.type = mujoco.mjtGeom.mjGEOM_BOX
            geom.pos, geom.size = list(box.centre), list(box.half_size)
        self.model = spec.compile()
        self.data = mujoco.MjData(self.model)
        self.robot = PandaRobot(self.model, self.data)
        self.data.qpos[self.robot.finger_qpos_idx] = FINGER_OPEN
        #: The validity test OMPL calls; it holds the planning model, not the planner (no reference cycle
        #: through OMPL, which Python's collector cannot see into).
        self.checker = CollisionChecker(self.model, self.data, self.robot)
        self.planner_name = planner
        bodies, geoms = fixture_elements(self.model)
        names = [self.model.geom(g).name for g in geoms]
        self._fixture_bodies = bodies
        self._fixture_geoms = np.array([g for g, n in zip(geoms, names) if not n.startswith("obstacle_")], dtype=int)
        lower = self.model.jnt_range[[self.model.joint(n).id for n in ARM_JOINTS], 0]
        upper = self.model.jnt_range[[self.model.joint(n).id for n in ARM_JOINTS], 1]
        self.space = ob.RealVectorStateSpace(len(ARM_JOINTS))
        bounds = ob.RealVectorBounds(len(ARM_JOINTS))
        for i, (low, high) in enumerate(zip(lower, upper)):
            bounds.setLow(i, float(low))
            bounds.setHigh(i, float(high))
        self.space.setBounds(bounds)
        self.setup = og.SimpleSetup(self.space)
        checker = self.checker
        self.setup.setStateValidityChecker(lambda state: checker([state[i] for i in range(len(ARM_JOINTS))]))
        self.setup.getSpaceInformation().setStateValidityCheckingResolution(resolution)
        # OMPL draws every generator's seed from one process-wide sequence, which ``plan`` restarts from
        # ``rng`` before each query.  The objects OMPL's first setup creates draw from it too: made here, once,
        # so that the first query of a process is planned as every later one with the same seed.
        self.setup.setPlanner(PLANNERS[planner](self.setup.getSpaceInformation()))
        self.setup.setup()
        self.reseed(seed)

    def reseed(self, seed: int) -> None:
        """Restart the generator the queries' OMPL seeds come from: a query's path is a function of the query
        and of the queries since the last ``reseed``, never of planning elsewhere in the process."""
        self.rng = np.random.default_rng(seed)

    @property
    def checks(self) -> int:
        """Collision checks (``is_valid`` calls, OMPL's included) since the planner was made."""
        return self.checker.checks

    def sync_objects(self, model: mujoco.MjModel, data: mujoco.MjData, names: list[str]) -> None:
        """Copy the poses of free bodies ``names`` from a live simulation into the planning model."""
        for name in names:
            source = model.jnt_qposadr[model.body_jntadr[model.body(name).id]]
            target = self.model.jnt_qposadr[self.model.body_jntadr[self.model.body(name).id]]
            self.data.qpos[target : target + 7] = data.qpos[source : source + 7]

    def sync_fixtures(self, model: mujoco.MjModel) -> None:
        """Copy the fixtures' poses and sizes from the live simulation's model (built from the same scene, so
        its fixtures are the same entries: ``ValueError`` otherwise)."""
        bodies, geoms = fixture_elements(model)
        if not np.array_equal(bodies, self._fixture_bodies) or len(geoms) != len(self._fixture_geoms):
            raise ValueError("the planner's scene has other fixtures than the model it is synced from")
        self.model.body_pos[bodies], self.model.body_quat[bodies] = model.body_pos[bodies], model.body_quat[bodies]
        for name in ("geom_pos", "geom_quat", "geom_size", "geom_rbound", "geom_aabb"):
            getattr(self.model, name)[self._fixture_geoms] = getattr(model, name)[geoms]  # in the same order

    def is_valid(self, arm_qpos: np.ndarray) -> bool:
        """No robot geom in contact with anything at ``arm_qpos`` (radians, (7,))."""
        return self.checker(arm_qpos)

    def plan(
        self, start: np.ndarray, goal: np.ndarray, time_limit: float = 2.0, planner: str | None = None
    ) -> PlanResult:
        """A simplified collision-free path from ``start`` to ``goal`` (arm joints, radians)."""
        name = planner or self.planner_name
        if name not in PLANNERS:
            raise ValueError(f"unknown planner {name!r}; valid: {sorted(PLANNERS)}")
        for label, q in (("start", start), ("goal", goal)):
            if not self.is_valid(np.asarray(q, dtype=float)):
                return PlanResult(False, np.zeros((0, 7)), 0.0, 0.0, f"{name} ({label} in collision)")
        self.setup.clear()
        ou.RNG.setSeed(int(self.rng.integers(1, 2**31)))  # OMPL refuses 0
        self.setup.setPlanner(PLANNERS[name](self.setup.getSpaceInformation()))
        start_state, goal_state = self.space.allocState(), self.space.allocState()
        for i in range(len(ARM_JOINTS)):
            start_state[i], goal_state[i] = float(start[i]), float(goal[i])
        self.setup.setStartAndGoalStates(start_state, goal_state)
        began = time.perf_counter()
        solved = self.setup.solve(time_limit) and self.setup.haveExactSolutionPath()
        if not solved:
            return PlanResult(False, np.zeros((0, 7)), 0.0, time.perf_counter() - began, name)
        self.setup.simplifySolution()
        seconds = time.perf_counter() - began
        geometric = self.setup.getSolutionPath()
        path = np.array([[geometric.getState(k)[i] for i in range(7)] for k in range(geometric.getStateCount())])
        return PlanResult(True, path, float(geometric.length()), seconds, name)


#: Joint acceleration and jerk caps for trajectory timing (half the Panda datasheet's accelerations).
MAX_ACCELERATION = np.array([7.5, 3.75, 5.0, 6.25, 7.5, 10.0, 10.0])
MAX_JERK = np.full(7, 500.0)


def time_parametrise(path: np.ndarray, max_velocity: np.ndarray, dt: float) -> np.ndarray:
    """Joint targets every ``dt`` seconds along waypoints (N, 7): time-optimal, jerk-limited and rest-to-rest
    between waypoints (ruckig), within ``max_velocity`` (rad/s) and ``MAX_ACCELERATION``."""
    from ruckig import InputParameter, Result, Ruckig, Trajectory

    generator, samples = Ruckig(7), []
    for start, end in zip(path, path[1:]):
        request = InputParameter(7)
        request.current_position, request.target_position = list(start), list(end)
        request.max_velocity = list(max_velocity)
        request.max_acceleration, request.max_jerk = list(MAX_ACCELERATION), list(MAX_JERK)
        trajectory = Trajectory(7)
        if generator.calculate(request, trajectory) not in (Result.Working, Result.Finished):
            raise ValueError(f"ruckig could not time the segment {start} -> {end}")
        times = np.append(np.arange(dt, trajectory.duration, dt), trajectory.duration)
        samples.extend(trajectory.at_time(t)[0] for t in times)
    return np.array(samples).reshape(-1, 7)
