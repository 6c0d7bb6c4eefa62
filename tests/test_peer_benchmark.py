"""The peer comparison's run-time patch of gymnasium-robotics changes only what MuJoCo 4 breaks."""

import dis
import inspect
import types

import gymnasium as gym
import mujoco
import numpy as np
import pytest

pytest.importorskip("gymnasium_robotics")

from benchmarks.env_throughput import FETCH_JOINT_HELPERS, patch_fetch_joint_checks  # noqa: E402

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)


def _lookups(function: types.FunctionType) -> list[tuple[str, object]]:
    """The function's global and attribute lookups (``mujoco``, ``mujoco.mjtJoint``, ...), in order."""
    kinds = {"LOAD_GLOBAL": "global", "LOAD_ATTR": "attribute", "LOAD_METHOD": "attribute"}
    return [(kinds[i.opname], i.argval) for i in dis.get_instructions(function) if i.opname in kinds]


def test_the_fetch_patch_casts_the_joint_type_and_leaves_every_other_lookup_alone():
    from gymnasium_robotics.utils import mujoco_utils

    before = dict(vars(mujoco_utils))
    patch_fetch_joint_checks()
    patch_fetch_joint_checks()  # twice: a no-op the second time
    after = vars(mujoco_utils)
    assert after["mujoco"] is mujoco  # the real module: no proxy in front of mujoco.X lookups
    changed = {name for name in before if after[name] is not before[name]}
    assert changed == set(FETCH_JOINT_HELPERS)
    for name in FETCH_JOINT_HELPERS:
        # The one change: the builtin int around the joint-type read; every other lookup the same, in order.
        lookups = _lookups(after[name])
        lookups.remove(("global", "int"))
        assert lookups == _lookups(before[name]), name
        assert after[name].__code__.co_consts == before[name].__code__.co_consts
        assert after[name].__globals__ is before[name].__globals__
        assert inspect.signature(after[name]) == inspect.signature(before[name])


def test_fetch_runs_on_this_mujoco_with_the_patch():
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    patch_fetch_joint_checks()
    env = gym.make("FetchPickAndPlace-v4")
    env.reset(seed=0)
    for action in np.random.default_rng(0).uniform(-1, 1, (5, 4)):
        env.step(action.astype(np.float32))
    env.close()
