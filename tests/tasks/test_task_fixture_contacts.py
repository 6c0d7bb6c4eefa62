"""A task counts the robot's contacts with its own fixtures in ``evaluate``, from the step's
``PrimitiveResult`` (docs/writing-a-task.md): nothing private needed."""

import mujoco
import numpy as np
import pytest

from panda_grasp_env.actions import encode_primitive
from panda_grasp_env.env import PandaEnv
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import TASKS, register_task
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import Task, TaskStep, with_scene


class WallTouches(Task):
    """One block before a wall at x = 0.55 m; ``info["wall_touches"]`` counts the primitives that touched it."""

    name = "WallTouchesTest"
    primitives = ("grasp", "push", "place")

    def __init__(self) -> None:
        self.touches = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        return with_scene(base, n_blocks=1, n_objects=0)

    def add_fixtures(self, spec: mujoco.MjSpec) -> None:
        body = spec.worldbody.add_body()
        body.name, body.pos = "wall", [0.55, 0.0, 0.04]
        geom = body.add_geom()
        geom.name, geom.type, geom.size = "wall_plate", mujoco.mjtGeom.mjGEOM_BOX, [0.01, 0.1, 0.04]

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict:
        cell.clear()
        cell.set_body_pose(int(cell.block_ids[0]), np.array([0.4, 0.2, 0.025]))
        cell.settle(0.2)
        self.touches = 0
        return {}

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        touched = result is not None and "wall" in [*result.transit_contacts, *result.work_contacts]
        self.touches += int(touched)
        return TaskStep(0.0, False, False, {"wall_touches": self.touches})


@pytest.fixture
def wall_task():
    register_task(WallTouches)
    yield WallTouches.name
    del TASKS[WallTouches.name]


def test_a_task_counts_its_fixture_contacts_from_the_primitive_result(wall_task):
    env = PandaEnv(task=wall_task, action_mode="primitive", primitive_z=True)
    env.reset(seed=0)
    primitives = env.task.primitives
    # A push along +x that ends 5 cm inside the wall, then one beside it that touches nothing.
    _, _, _, _, info = env.step(encode_primitive(primitives, True, "push", 0.45, 0.0, 0.0, 0.03))
    assert info["primitive_reason"] == "collision" and info["wall_touches"] == 1
    _, _, _, _, info = env.step(encode_primitive(primitives, True, "push", 0.3, -0.2, 0.0, 0.03))
    assert info["wall_touches"] == 1
    env.close()
