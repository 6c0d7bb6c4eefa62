"""Versioned Gymnasium ids, registered when ``panda_grasp_env`` is imported.

``gymnasium.make("panda_grasp_env:PandaTowerBuild-v0", obs_mode=..., action_mode=...)``
works in a fresh interpreter: Gymnasium imports this package first.  Any env or
task option can be passed to ``make``; ``max_episode_steps`` suits the id's
default action mode and can be overridden the usual way.
"""

from __future__ import annotations

import gymnasium as gym

ENTRY_POINT = "panda_grasp_env.env:PandaEnv"

#: id -> (default keyword arguments, max_episode_steps)
ENV_IDS: dict[str, tuple[dict, int]] = {
    # Primitive tasks: steps are motion primitives (~4 s simulated each).
    "PandaTowerBuild-v0": ({"task": "TowerBuild"}, 30),
    "PandaTowerBreak-v0": ({"task": "TowerBreak"}, 5),
    "PandaTowerBreakDirectional-v0": ({"task": "TowerBreak", "directional": True}, 5),
    "PandaBuildAndBreak-v0": ({"task": "BuildAndBreak"}, 100),
    "PandaGraspClutter-v0": ({"task": "Grasp", "clutter": True}, 60),
    # Goal-conditioned in the low-level modes (the default for Push and Stack; Grasp defaults to primitives, and
    # ee_delta makes it the lift task): 50 steps of 40 ms, or 50 primitives.
    "PandaGrasp-v0": ({"task": "Grasp"}, 50),
    "PandaPush-v0": ({"task": "Push"}, 50),
    "PandaStack-v0": ({"task": "TowerBuild", "n_blocks": 2, "action_mode": "ee_delta"}, 100),
}


def register_envs() -> None:
    for env_id, (kwargs, max_steps) in ENV_IDS.items():
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point=ENTRY_POINT, kwargs=kwargs, max_episode_steps=max_steps)
