"""Inverse kinematics for full 6-DOF grasp-site poses, with random restarts and the source study's tolerance sampler.

``PoseIK.solve`` runs mink's differential IK to convergence on the robot-only
model (the simulation's kinematics) from a start configuration, then from
seeded random restarts; a posture task keeps the elbow sensible.
``ToleranceSampler`` wraps it: if the exact goal orientation has no
solution, orientations in zenith / azimuth / roll windows around it are tried,
ordered from the middle outward, and the first feasible one wins -- the
technique that raised reachability from 59.5 % to 92.9 % in the source study
(10 deg zenith, 20 deg azimuth).

Rotations are (3, 3) matrices of the grasp site in the world frame: x is the
closing axis, z the approach direction.  Angles in radians, lengths in metres.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import mink
import numpy as np

from panda_grasp_env.geometry import rotation_about
from panda_grasp_env.model.robot import HOME_QPOS
from panda_grasp_env.model.scene import ARM_JOINTS, GRASP_SITE, SceneConfig, build_spec


@dataclass(frozen=True)
class IKResult:
    """A solution: arm joint angles (7,), the orientation actually reached, its error, iterations used."""

    qpos: np.ndarray
    rotation: np.ndarray
    position_error: float
    angle_error: float
    iterations: int


class PoseIK:
    """Position + orientation IK for the grasp site (mink, daqp), within joint limits."""

    def __init__(
        self,
        scene_config: SceneConfig | None = None,
        position_tolerance: float = 0.001,
        angle_tolerance: float = np.deg2rad(1.0),
        max_iterations: int = 100,
        restarts: int = 3,
    ) -> None:
        self.model = build_spec(scene_config or SceneConfig(), with_environment=False).compile()
        self.configuration = mink.Configuration(self.model)
        self.arm = np.array([self.model.jnt_qposadr[self.model.joint(n).id] for n in ARM_JOINTS])
        self.lower = self.model.jnt_range[[self.model.joint(n).id for n in ARM_JOINTS], 0]
        self.upper = self.model.jnt_range[[self.model.joint(n).id for n in ARM_JOINTS], 1]
        self.frame = mink.FrameTask(GRASP_SITE, "site", position_cost=1.0, orientation_cost=1.0, lm_damping=1e-2)
        self.posture = mink.PostureTask(self.model, cost=1e-3)
        home = self.configuration.q.copy()
        home[self.arm] = HOME_QPOS
        self.posture.set_target(home)
        self.limits = [mink.ConfigurationLimit(self.model, gain=0.95)]
        self.position_tolerance, self.angle_tolerance = position_tolerance, angle_tolerance
        self.max_iterations, self.restarts = max_iterations, restarts

    def _descend(self, start: np.ndarray) -> tuple[np.ndarray, float, float, int]:
        q = self.configuration.q.copy()
        q[self.arm] = start
        self.configuration.update(q)
        iterations = 0
        while iterations < self.max_iterations:
            iterations += 1
            velocity = mink.solve_ik(
                self.configuration, [self.frame, self.posture], 0.1, "daqp", damping=1e-3, limits=self.limits
            )
            self.configuration.integrate_inplace(velocity, 0.1)
            error = self.frame.compute_error(self.configuration)
            position_error, angle_error = float(np.linalg.norm(error[:3])), float(np.linalg.norm(error[3:]))
            if position_error < self.position_tolerance and angle_error < self.angle_tolerance:
                break
        return self.configuration.q[self.arm].copy(), position_error, angle_error, iterations

    def solve(
        self,
        position: np.ndarray,
        rotation: np.ndarray,
        start: np.ndarray,
        rng: np.random.Generator,
        restarts: int | None = None,
    ) -> IKResult | None:
        """Joint angles placing the grasp site at ``position`` with ``rotation``, or None.

        Tries from ``start`` first, then from ``restarts`` (default: the solver's) random
        configurations drawn from ``rng``.
        """
        target = mink.SE3.from_rotation_and_translation(
            mink.SO3.from_matrix(np.asarray(rotation)), np.asarray(position)
        )
        self.frame.set_target(target)
        restarts = self.restarts if restarts is None else restarts
        starts = [np.asarray(start, dtype=float)] + [rng.uniform(self.lower, self.upper) for _ in range(restarts)]
        for begin in starts:
            qpos, position_error, angle_error, iterations = self._descend(begin)
            if position_error < self.position_tolerance and angle_error < self.angle_tolerance:
                return IKResult(qpos, np.asarray(rotation), position_error, angle_error, iterations)
        return None


@dataclass(frozen=True)
class ToleranceSampler:
    """Orientations around a goal, middle outward: zenith tilts the approach axis, azimuth turns the tilt's
    direction about the world vertical, roll turns the hand about its approach axis (radians, half-windows)."""

    zenith: float = np.deg2rad(10)
    azimuth: float = np.deg2rad(20)
    roll: float = np.deg2rad(20)
    steps: int = 2  # samples per side of each window

    def orientations(self, rotation: np.ndarray) -> Iterator[np.ndarray]:
        """The goal first, then perturbed orientations in order of growing total deviation."""
        grid = []
        for zenith in np.linspace(-self.zenith, self.zenith, 2 * self.steps + 1):
            for azimuth in np.linspace(-self.azimuth, self.azimuth, 2 * self.steps + 1):
                for roll in np.linspace(-self.roll, self.roll, 2 * self.steps + 1):
                    deviation = abs(zenith) / max(self.zenith, 1e-9) + abs(azimuth) / max(self.azimuth, 1e-9)
                    deviation += abs(roll) / max(self.roll, 1e-9)
                    grid.append((deviation, zenith, azimuth, roll))
        grid.sort(key=lambda item: item[0])
        approach = rotation[:, 2]
        horizontal = np.cross(approach, [0.0, 0.0, 1.0])
        tilt_axis = horizontal / np.linalg.norm(horizontal) if np.linalg.norm(horizontal) > 1e-6 else rotation[:, 0]
        seen = set()
        for _, zenith, azimuth, roll in grid:
            key = (round(zenith, 6), round(azimuth, 6), round(roll, 6))
            if key in seen or (zenith == 0.0 and azimuth != 0.0):  # azimuth means nothing without tilt
                continue
            seen.add(key)
            tilt = rotation_about(rotation_about([0.0, 0.0, 1.0], azimuth) @ tilt_axis, zenith)
            yield tilt @ rotation @ rotation_about([0.0, 0.0, 1.0], roll)

    def solve(
        self, ik: PoseIK, position: np.ndarray, rotation: np.ndarray, start: np.ndarray, rng: np.random.Generator
    ) -> tuple[IKResult | None, int]:
        """The first feasible orientation's solution (or None), and how many orientations were tried."""
        tried = 0
        for candidate in self.orientations(np.asarray(rotation, dtype=float)):
            # Random restarts for the goal itself; the perturbed orientations start from ``start`` only.
            result = ik.solve(position, candidate, start, rng, restarts=None if tried == 0 else 0)
            tried += 1
            if result is not None:
                return result, tried
        return None, tried
