"""Will it stand?  A what-if run on a copy of the simulation: move some free bodies to new poses, let the scene
run a while, and measure how far the watched bodies move.  The live simulation is not touched.  World frame,
metres, radians.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from panda_grasp_env.geometry import yaw_quaternion

#: How long (seconds of simulated time) a what-if runs: a piece that will fall has tipped well past its
#: tolerances by then (a cube tipping off an edge turns ~20 degrees in 0.3 s).
SETTLE_TIME = 1.0
#: A watched body that moves less than this (metres), and turns less than ``STILL_TURN`` (radians), stood.
STILL_SHIFT, STILL_TURN = 0.004, np.deg2rad(4.0)


@dataclass(frozen=True)
class WhatIf:
    """What a what-if run found: the largest shift (metres) and turn (radians) of a watched body, and the
    simulated seconds it ran."""

    shift: float
    turn: float
    seconds: float

    @property
    def stands(self) -> bool:
        """Whether every watched body stayed within ``STILL_SHIFT`` and ``STILL_TURN``."""
        return self.shift < STILL_SHIFT and self.turn < STILL_TURN


def set_free_pose(model: mujoco.MjModel, data: mujoco.MjData, body: int, position: np.ndarray, yaw: float) -> None:
    """Put free body ``body`` upright at ``position`` (world metres) turned ``yaw`` radians about z, at rest."""
    joint = model.body_jntadr[body]
    if joint < 0 or model.jnt_type[joint] != mujoco.mjtJoint.mjJNT_FREE:
        raise ValueError(f"body {body} has no free joint to move")
    qpos, dof = model.jnt_qposadr[joint], model.jnt_dofadr[joint]
    data.qpos[qpos : qpos + 3] = position
    data.qpos[qpos + 3 : qpos + 7] = yaw_quaternion(yaw)
    data.qvel[dof : dof + 6] = 0.0


def what_if(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    moves: Mapping[int, tuple[np.ndarray, float]],
    watched: Sequence[int],
    seconds: float = SETTLE_TIME,
) -> WhatIf:
    """On a copy of ``data``: put each body of ``moves`` at its (position, yaw) (``set_free_pose``), run
    ``seconds`` with the controls as they are (the arm holds its pose), and measure the ``watched`` bodies
    against where they were after the moves."""
    trial = copy.copy(data)
    for body, (position, yaw) in moves.items():
        set_free_pose(model, trial, int(body), np.asarray(position, dtype=float), float(yaw))
    mujoco.mj_forward(model, trial)
    watched = list(map(int, watched))
    start_position, start_rotation = trial.xpos[watched].copy(), trial.xmat[watched].reshape(-1, 3, 3).copy()
    mujoco.mj_step(model, trial, nstep=int(round(seconds / model.opt.timestep)))
    shift = np.linalg.norm(trial.xpos[watched] - start_position, axis=1)
    relative = np.einsum("nij,nik->njk", start_rotation, trial.xmat[watched].reshape(-1, 3, 3))
    turn = np.arccos(np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0))
    return WhatIf(float(shift.max(initial=0.0)), float(turn.max(initial=0.0)), seconds)
