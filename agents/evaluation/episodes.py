"""One benchmark episode: its env and agent, made from its ``EpisodeSpec``, and the step loop that plays it.

``evaluate.py``'s worker processes play their episodes through ``run_episode``; training evaluates policies
through ``play_episode``.
"""

from __future__ import annotations

import atexit
import time
from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.evaluation.protocol import (
    AGENTS,
    PERCEPTION,
    EpisodeSpec,
    baseline,
    learned_env,
    phased_env,
)
from panda_grasp_env.agents.policies.random_agent import RandomAgent
from panda_grasp_env.agents.policies.registry import EXPERTS, NAMED_AGENTS


def make_env(spec: EpisodeSpec) -> gym.Env:
    """A new env for ``spec``: the task's benchmark env (with ``PERCEPTION``, or the benchmark's own
    ``perception``, for the planned and oracle agents,
    a learned checkpoint's own observations and actions for it: ``learned_env``; a phased agent's: ``phased_env``),
    the spec's options on top."""
    from panda_grasp_env.agents.policies.phased import PHASED_AGENTS

    if spec.agent in PHASED_AGENTS:
        return phased_env(spec.agent, spec.task, **spec.make_options)
    if spec.agent not in AGENTS and spec.agent not in NAMED_AGENTS:  # a learned checkpoint: its options on the task
        from panda_grasp_env.agents.policies.learned import Checkpoint

        return learned_env(Checkpoint(spec.agent), spec.task, **spec.make_options)
    benchmark = BENCHMARKS[spec.task]
    options = dict(benchmark.options)
    if spec.agent in ("planned", "oracle"):  # they see the scene through cameras
        options |= PERCEPTION if benchmark.perception is None else benchmark.perception
    if spec.agent in NAMED_AGENTS:
        options |= NAMED_AGENTS[spec.agent].env_options
    return gym.make(f"panda_grasp_env:{benchmark.env_id}", **(options | spec.make_options))  # the spec's options win


def make_agent(spec: EpisodeSpec, env: gym.Env) -> Any:
    """The agent ``spec`` names, seeded from its seed, for ``env``."""
    if spec.agent == "random":
        return RandomAgent(env.action_space, seed=spec.seed)
    if spec.agent == "expert":
        return EXPERTS[spec.task]()
    if spec.agent in NAMED_AGENTS:
        return NAMED_AGENTS[spec.agent].factory(env, spec.seed)
    from panda_grasp_env.agents.policies.phased import PHASED_AGENTS, PhasedAgent

    if spec.agent in PHASED_AGENTS:
        return PhasedAgent(spec.agent, env)
    if spec.agent not in AGENTS:
        from panda_grasp_env.agents.policies.learned import LearnedAgent

        return LearnedAgent(spec.agent, env)
    return baseline(spec.task)(env, spec.seed, spec.agent == "oracle")  # type: ignore[misc]


#: The env of this process's last episode and what it was made for (agent, task, options), or None: the next
#: episode reuses it if it needs the same env (``episode_env``).
_kept: tuple[tuple[str, str, tuple[tuple[str, Any], ...]], gym.Env] | None = None


def episode_env(spec: EpisodeSpec) -> gym.Env:
    """The env ``spec`` runs in: the previous episode's if that was made for the same agent, task and options,
    else a new one (the previous is closed).  A used env reset with a seed plays exactly the episode a new one
    does.  Making an env takes about 0.1 s, as long as a whole Push episode, and the memory a closed env
    frees mostly stays with the process (glibc's heap): a new env per episode made long runs slow, and
    several GB large."""
    global _kept
    key = (spec.agent, spec.task, spec.options)
    if _kept is None or _kept[0] != key:
        close_kept_env()
        _kept = (key, make_env(spec))
    return _kept[1]


def close_kept_env() -> None:
    """Close the env kept for the next episode, if any."""
    global _kept
    if _kept is not None:
        env, _kept = _kept[1], None
        env.close()


atexit.register(close_kept_env)  # a caller that never closes it (its renderers included) does so at exit


def clip_path(out: Path, spec: EpisodeSpec) -> Path:
    """Where a run in folder ``out`` keeps the clip of ``spec``'s (agent, task): one MP4 per pair, of its first
    seed."""
    return out / "videos" / f"{spec.agent}_{spec.task}.mp4"


def first_of_each_pair(specs: list[EpisodeSpec]) -> list[EpisodeSpec]:
    """The first spec of each (agent, task) pair, in the order of ``specs``: the episodes a run films."""
    return list({(s.agent, s.task): s for s in reversed(specs)}.values())[::-1]


def run_episode(spec: EpisodeSpec, video: Path | None = None) -> dict[str, Any]:
    """Run one episode; returns its deterministic outcome under ``result`` and wall-clock figures under ``timing``."""
    from panda_grasp_env.tooling.video import VideoRecorder

    env = episode_env(spec)
    try:
        agent = make_agent(spec, env)
        recorder = None
        if video is not None:
            recorder = VideoRecorder(
                env.unwrapped.cell, video, "front", 384, 288, every=5, profile="fast", active=False
            )
            recorder.caption = f"{spec.agent} on {spec.task}, seed {spec.seed}"
        outcome = play_episode(env, agent, spec, recorder)
        if recorder is not None:
            recorder.save()
    except BaseException:  # an env left mid-episode (a recorder still attached) is not reused
        close_kept_env()
        raise
    return outcome


def play_episode(env: gym.Env, agent: Any, spec: EpisodeSpec, recorder: Any = None) -> dict[str, Any]:
    """The benchmark's step loop: reset ``env`` with ``spec.seed`` and let ``agent`` act until the episode ends."""
    began = time.perf_counter()
    reset_options = BENCHMARKS[spec.task].reset_options
    observation, info = env.reset(seed=spec.seed, options=None if reset_options is None else reset_options(spec.seed))
    agent.reset(observation, info)
    if recorder is not None:  # the clip starts at the episode's first state
        recorder.active = True
    meshes = [o["mesh"] for o in info.get("objects", []) if "mesh" in o]
    first_grasp = None  # whether the episode's first grasp attempt succeeded
    in_play = info.get("objects_remaining")
    ideal = env.unwrapped.task.ideal_actions if in_play is None else in_play
    decisions, actions, disturbed, transit_contacts = [], 0, 0, 0
    failures: Counter[str] = Counter()
    task_facts = dict(info)  # the latest of each info key: a diverged step reports no task keys (cycles, objects)
    while True:
        start = time.perf_counter()
        action = agent.act(observation, info)
        decisions.append(time.perf_counter() - start)
        observation, _, terminated, truncated, info = env.step(action)
        actions += 1
        disturbed += info.get("disturbed", 0)  # primitive steps only: low-level steps have no collateral keys
        transit_contacts += info.get("transit_contacts", 0)
        task_facts.update(info)
        if first_grasp is None and info.get("primitive") == "grasp":
            first_grasp = bool(info["primitive_success"])
        if "primitive_reason" in info and not info["primitive_success"]:
            failures[info["primitive_reason"]] += 1
        if recorder is not None and "primitive" in info:
            recorder.status = f"{info['primitive']}: {info['primitive_reason']}"
        if terminated or truncated:
            break
    failures.update({k: v for k, v in getattr(agent, "failures", {}).items() if k == "no_candidate"})
    if spec.task == "BuildAndBreak":  # the ideal is per build-and-break cycle
        ideal = ideal * int(task_facts.get("cycles", 0))
    success = bool(info["is_success"])
    limit = env.spec.max_episode_steps if env.spec is not None else None
    grasping = spec.task.startswith("Grasp") and "primitive_reason" in task_facts
    result = {
        "spec": spec.record(),
        "success": success,
        "completion": bool(task_facts.get("objects_remaining", 1) == 0) if grasping else success,
        "actions": actions,
        "ideal_actions": int(ideal),
        "grasps_attempted": int(info["grasps_attempted"]),
        "grasps_succeeded": int(info["grasps_succeeded"]),
        "cycles": int(task_facts.get("cycles", 0)),
        "sim_seconds": round(float(info["sim_time"]), 6),
        "failures": dict(sorted(failures.items())),
        "failure": episode_failure(success, terminated, truncated, info, limit is not None and actions >= limit),
        "physics_error": bool(info["physics_error"]),
        "disturbed": int(disturbed),
        "transit_contacts": int(transit_contacts),
        **({"first_grasp": bool(first_grasp)} if grasping else {}),  # no grasp attempted: False
        **({"meshes": meshes} if meshes else {}),
        **(
            {"structure": str(task_facts["structure"]), "tier": int(task_facts["tier"])} if "tier" in task_facts else {}
        ),
    }
    timing = {"wall_seconds": time.perf_counter() - began, "decision_seconds_median": float(np.median(decisions))}
    return {"result": result, "timing": timing}


def episode_failure(
    success: bool, terminated: bool, truncated: bool, info: dict[str, Any], out_of_steps: bool
) -> str | None:
    """Why an episode ended without success (None if it succeeded), from its last step's ``info``: the
    simulation diverged; a directional break toppled the tower the wrong way; a failed primitive knocked the
    tower over; a built tower fell; objects left the workspace; the task's own ``failure_reason``; the step
    limit (``out_of_steps``) ran out;
    the task gave up (Grasp's K consecutive failures); or else the MDP ended lost (a block set aside or out of
    reach)."""
    if success:
        return None
    for flag, reason in (
        ("physics_error", "physics_error"),
        ("wrong_direction", "wrong_direction"),
        ("broken_by_failure", "knocked_over_by_failed_primitive"),
        ("tower_fell", "tower_fell"),
        ("objects_lost", "objects_lost"),
    ):
        if info.get(flag):
            return reason
    if info.get("failure_reason"):  # a task's own name for it (StructureBuild's collapsed, scaffold_left, ...)
        return str(info["failure_reason"])
    if out_of_steps:
        return "step_limit"
    return "gave_up" if truncated else "lost"
