"""Physics timing shared by the speed benchmarks; imports only MuJoCo and numpy, so it also runs in the
peer environments the benchmarks build (Fetch on another MuJoCo)."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np


@dataclass
class PhysicsTime:
    """Wall seconds spent inside ``mujoco.mj_step`` and the physics steps it made."""

    seconds: float = 0.0
    steps: int = 0


@contextmanager
def timed_mj_step() -> Iterator[PhysicsTime]:
    """Time every ``mujoco.mj_step`` call made through the module (ours and gymnasium-robotics' envs both
    call it so) while the block runs; the caller may reset the returned counts between measurements."""
    step, record = mujoco.mj_step, PhysicsTime()

    def timed_step(model: Any, data: Any, nstep: int = 1) -> None:
        started = time.perf_counter()
        step(model, data, nstep=nstep)
        record.seconds += time.perf_counter() - started
        record.steps += nstep

    mujoco.mj_step = timed_step
    try:
        yield record
    finally:
        mujoco.mj_step = step


def raw_step_rate(model: Any, data: Any, steps: int) -> float:
    """``mj_step`` calls per second from ``data``'s state with its controls held (on a copy of the data)."""
    spec = mujoco.mjtState.mjSTATE_INTEGRATION
    snapshot = np.empty(mujoco.mj_stateSize(model, spec))
    mujoco.mj_getState(model, data, snapshot, spec)
    copy = mujoco.MjData(model)
    mujoco.mj_setState(model, copy, snapshot, spec)
    mujoco.mj_forward(model, copy)
    start = time.perf_counter()
    mujoco.mj_step(model, copy, nstep=steps)
    return steps / (time.perf_counter() - start)
