"""Benchmark episodes of any agent on any task through ``env.step``: specs, runner, aggregation.

``evaluate.py`` is the command line; this module is what its worker processes import.
An episode is fully determined by (agent, task, seed): the env is reset with the
seed and every agent draws from generators seeded from it, so results repeat
bit for bit, in any process, in any order.
"""

from __future__ import annotations

import atexit
import functools
import importlib
import importlib.util
import json
import os
import sys
import time
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

# The built-in planned agents and experts register themselves (``registry``) when their modules are imported.
import panda_grasp_env.agents.experts
import panda_grasp_env.agents.grasping
import panda_grasp_env.agents.put_in_bin
import panda_grasp_env.agents.towers  # noqa: F401
from panda_grasp_env.actions import ACTION_MODES
from panda_grasp_env.agents.random_agent import RandomAgent
from panda_grasp_env.agents.registry import BASELINES, EXPERTS
from panda_grasp_env.env import AGENT_OPTIONS
from panda_grasp_env.registration import BENCHMARK_RESET_OPTIONS, BENCHMARKS, ENV_IDS, TASKS

if TYPE_CHECKING:
    from panda_grasp_env.agents.learned import Checkpoint

#: Perception agents get RGB-D from both cameras at 640 x 480 (``PERCEPTION``).
#: The built-in agents; every shipped checkpoint (``panda_grasp_env.agents.learned.available_checkpoints``) is an agent too.
AGENTS = ("random", "planned", "oracle", "expert")


def import_modules(names: Iterable[str]) -> None:
    """Import the modules that register tasks and agents from outside the package (``evaluate.py --import``):
    dotted module names, looked up on the Python path and in the current folder, or paths of ``.py`` files.
    ``ValueError`` names one that does not import.  Worker processes call it too, before their first episode."""
    if os.getcwd() not in sys.path:
        sys.path.append(os.getcwd())
    for name in names:
        try:
            if name.endswith(".py"):
                path = Path(name).resolve()
                module_name = path.stem
                if getattr(sys.modules.get(module_name), "__file__", None) == str(path):
                    continue  # imported already: its tasks and agents are registered
                spec = importlib.util.spec_from_file_location(module_name, path)
                if spec is None or spec.loader is None or not path.is_file():
                    raise ImportError(f"no Python file at {path}")
                module = importlib.util.module_from_spec(spec)
                sys.modules[module_name] = module
                try:
                    spec.loader.exec_module(module)
                except BaseException:
                    del sys.modules[module_name]
                    raise
            else:
                importlib.import_module(name)
        except (ImportError, ValueError) as error:
            raise ValueError(f"--import {name}: {type(error).__name__}: {error}") from None


def action_mode_of(env_id: str, options: dict[str, Any]) -> str:
    """The action mode ``gymnasium.make(env_id, **options)`` gets (an explicit option, else the id's task default)."""
    registered = ENV_IDS[env_id][0]
    return options.get("action_mode") or registered.get("action_mode") or TASKS[registered["task"]].default_action_mode


def is_low_level(env_id: str, options: dict[str, Any]) -> bool:
    """Whether that env acts at 25 Hz (the action mode's ``low_level``) rather than through motion primitives."""
    name = action_mode_of(env_id, options)
    return isinstance(name, str) and name in ACTION_MODES and ACTION_MODES[name].low_level


def task_label(env_id: str, env_kwargs: dict[str, Any]) -> str:
    """The ``evaluate.py`` task whose env (id, low-level or not) a policy trained on ``env_id`` plays, else ``env_id``."""
    low_level = is_low_level(env_id, env_kwargs)
    for task, (task_env_id, options) in BENCHMARKS.items():
        if task_env_id == env_id and is_low_level(task_env_id, options) == low_level:
            return task
    return env_id


def all_agents() -> tuple[str, ...]:
    """Built-in agents, then the shipped learned checkpoints by name, then the phased agents made of them."""
    from panda_grasp_env.agents.learned import available_checkpoints
    from panda_grasp_env.agents.phased import PHASED_AGENTS

    return (*AGENTS, *available_checkpoints(), *PHASED_AGENTS)


def skip_reason(agent: str, task: str) -> str | None:
    """Why ``agent`` does not apply to ``task`` (None if it does)."""
    if agent == "random":
        return None
    if agent == "expert":
        return None if task in EXPERTS else f"no scripted low-level expert is written for {task}"
    if agent in AGENTS:
        if is_low_level(*BENCHMARKS[task]):
            return f"the {agent} baselines act through motion primitives; {task} is a low-level ee_delta task"
        if task not in BASELINES:
            return f"no {agent} agent is written for {task}"
        return None
    from panda_grasp_env.agents.phased import PHASED_AGENTS

    if agent in PHASED_AGENTS:
        tasks = PHASED_AGENTS[agent].tasks
        return None if task in tasks else f"the phased agent {agent} plays {', '.join(tasks)}"
    return learned_skip_reason(agent, task)


def learned_skip_reason(agent: str, task: str) -> str | None:
    """Why checkpoint ``agent`` does not play ``task`` (None if it does).

    A checkpoint plays the task it was trained for, and any other benchmark task of the same registered task
    at the same level of action (motion primitives or 25 Hz control) whose env, seen and acted on as the
    checkpoint was trained (``learned_env``), has the observation and action spaces it was trained on: a
    heightmap grasping policy trained on packed layouts plays random heaps and single objects too."""
    from panda_grasp_env.agents.learned import Checkpoint

    checkpoint = Checkpoint(agent)
    config = checkpoint.config
    if checkpoint.task == task:
        return None
    trained_for = f"checkpoint {agent} was trained for {checkpoint.task} ({config.env_id})"
    env_id, options = BENCHMARKS[task]
    if ENV_IDS[env_id][0]["task"] != ENV_IDS[config.env_id][0]["task"]:
        return trained_for
    if is_low_level(env_id, options) != is_low_level(config.env_id, config.env_kwargs):
        return f"{trained_for}, at the other level of action"
    card = (checkpoint.path / "checkpoint.json").read_text()
    differs = _space_differing(checkpoint.path.resolve(), card, checkpoint.provenance()["policy_sha256"], task)
    return None if differs is None else f"{trained_for}; {task}'s {differs} differs with its env options"


@functools.cache
def _space_differing(path: Path, card: str, weights: str, task: str) -> str | None:
    """The space (observation or action) in which ``task``'s env for the checkpoint at ``path`` differs from the
    one it was trained on, or None; once per checkpoint folder, card, weights and task: it makes two envs."""
    from panda_grasp_env.agents.learned import Checkpoint

    checkpoint = Checkpoint(path)
    with checkpoint.make_env() as trained, learned_env(checkpoint, task) as benchmark:
        for name in ("observation_space", "action_space"):
            if getattr(trained, name) != getattr(benchmark, name):
                return name.replace("_", " ")
    return None


def learned_env(checkpoint: Checkpoint, task: str, **options: Any) -> gym.Env:
    """The env a shipped checkpoint plays benchmark ``task`` in: on its own task the env it was trained on
    (``Checkpoint.make_env``); on another, that task's id with its scene and protocol options, seen and acted
    on as the checkpoint was trained (its ``AGENT_OPTIONS``); ``options`` on top of either."""
    if task == checkpoint.task:
        return checkpoint.make_env(**options)
    env_id, benchmark = BENCHMARKS[task]
    scene = {key: value for key, value in benchmark.items() if key not in AGENT_OPTIONS}
    agent = {key: value for key, value in checkpoint.config.env_kwargs.items() if key in AGENT_OPTIONS}
    return gym.make(f"panda_grasp_env:{env_id}", **(scene | agent | options))


PERCEPTION = {"obs_mode": "rgbd", "cameras": ("overhead", "front"), "image_size": (640, 480)}


class FrozenMapping(tuple):
    """A mapping option value (an ``objects`` spec, ``randomization``, ``size_ranges``) as sorted (key, value)
    pairs: hashable, so that it can be part of an episode's spec."""


def frozen(value: Any) -> Any:
    """An option value made hashable: lists and tuples as tuples, mappings as ``FrozenMapping``, all the way
    down; ``ValueError`` for a value that cannot be."""
    if isinstance(value, FrozenMapping):
        return value
    if isinstance(value, (list, tuple)):
        return tuple(frozen(v) for v in value)
    if isinstance(value, Mapping):
        return FrozenMapping(sorted((str(k), frozen(v)) for k, v in value.items()))
    try:
        hash(value)
    except TypeError:
        raise ValueError(f"option values must be YAML scalars, lists or mappings, got {value!r}") from None
    return value


def thawed(value: Any) -> Any:
    """An option value as ``gymnasium.make`` and JSON take it: ``frozen`` undone (mappings as dicts, sequences
    as lists)."""
    if isinstance(value, FrozenMapping):
        return {k: thawed(v) for k, v in value}
    if isinstance(value, tuple):
        return [thawed(v) for v in value]
    return value


@dataclass(frozen=True)
class EpisodeSpec:
    """One benchmark episode: which agent plays which task on which seed, with which extra env options."""

    agent: str
    task: str
    seed: int
    #: ``gymnasium.make`` options on top of the task's (``evaluate.py --task-options``): (key, value) pairs
    #: sorted by key, values ``frozen`` (given as lists or mappings, they are frozen here).
    options: tuple[tuple[str, Any], ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", tuple(sorted((str(k), frozen(v)) for k, v in self.options)))

    @property
    def make_options(self) -> dict[str, Any]:
        """The options as ``gymnasium.make`` takes them (``thawed``)."""
        return {key: thawed(value) for key, value in self.options}

    @property
    def key(self) -> str:
        """``agent/task/seed``, and the options as JSON if any (nested lists and mappings written out)."""
        key = f"{self.agent}/{self.task}/{self.seed}"
        return f"{key}/{json.dumps(self.make_options, sort_keys=True)}" if self.options else key

    def record(self) -> dict[str, Any]:
        """The spec as an episode record holds it: the options as [key, value] pairs, values as JSON."""
        options = [[key, thawed(value)] for key, value in self.options]
        return {"agent": self.agent, "task": self.task, "seed": self.seed, "options": options}


def task_options_from_pairs(pairs: list[str], tasks: list[str]) -> dict[str, Any]:
    """``KEY=VALUE`` strings (``--task-options``) as a mapping of YAML values, checked by making each of the
    ``tasks``' envs with them; ``ValueError`` naming the bad pair or option."""
    import yaml

    options: dict[str, Any] = {}
    for pair in pairs:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"--task-options: {pair!r} is not KEY=VALUE")
        try:
            value = yaml.safe_load(text)
            frozen(value)  # a value an episode's spec can hold
        except (yaml.YAMLError, ValueError) as error:
            raise ValueError(f"--task-options {key}: {error}") from None
        options[key.strip()] = value
    for task in tasks if options else ():
        env_id, task_defaults = BENCHMARKS[task]
        try:  # an option the protocol sets too (max_episode_steps on BuildAndBreak) is overridden
            gym.make(f"panda_grasp_env:{env_id}", **(task_defaults | options)).close()
        except (ValueError, TypeError) as error:
            raise ValueError(f"--task-options on {task} ({env_id}): {error}") from None
    return options


def phased_env(name: str, task: str, **options: Any) -> gym.Env:
    """The env phased agent ``name`` plays ``task`` in: the task's scene, seen and acted on as its first part
    was trained (``learned_env``)."""
    from panda_grasp_env.agents.learned import Checkpoint
    from panda_grasp_env.agents.phased import PHASED_AGENTS

    return learned_env(Checkpoint(PHASED_AGENTS[name].first), task, **options)


def make_env(spec: EpisodeSpec) -> gym.Env:
    from panda_grasp_env.agents.phased import PHASED_AGENTS

    if spec.agent in PHASED_AGENTS:
        return phased_env(spec.agent, spec.task, **spec.make_options)
    if spec.agent not in AGENTS:  # a learned checkpoint: its env options on the task's scene
        from panda_grasp_env.agents.learned import Checkpoint

        return learned_env(Checkpoint(spec.agent), spec.task, **spec.make_options)
    env_id, options = BENCHMARKS[spec.task]
    options = dict(options)
    if spec.agent in ("planned", "oracle"):  # they see the scene through cameras
        options |= PERCEPTION
    return gym.make(f"panda_grasp_env:{env_id}", **(options | spec.make_options))  # the spec's options win


def make_agent(spec: EpisodeSpec, env: gym.Env) -> Any:
    if spec.agent == "random":
        return RandomAgent(env.action_space, seed=spec.seed)
    if spec.agent == "expert":
        return EXPERTS[spec.task]()
    from panda_grasp_env.agents.phased import PHASED_AGENTS, PhasedAgent

    if spec.agent in PHASED_AGENTS:
        return PhasedAgent(spec.agent, env)
    if spec.agent not in AGENTS:
        from panda_grasp_env.agents.learned import LearnedAgent

        return LearnedAgent(spec.agent, env)
    return BASELINES[spec.task](env, spec.seed, spec.agent == "oracle")


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


def run_episode(spec: EpisodeSpec, video: Path | None = None) -> dict[str, Any]:
    """Run one episode; returns its deterministic outcome under ``result`` and wall-clock figures under ``timing``."""
    from panda_grasp_env.tooling.video import VideoRecorder

    env = episode_env(spec)
    try:
        agent = make_agent(spec, env)
        recorder = None
        if video is not None:
            recorder = VideoRecorder(env.unwrapped.cell, "front", 480, 360, every=4, profile="fast")
            recorder.caption = f"{spec.agent} on {spec.task}, seed {spec.seed}"
        outcome = play_episode(env, agent, spec, recorder)
        if recorder is not None:
            recorder.save(video)
    except BaseException:  # an env left mid-episode (a recorder still attached) is not reused
        close_kept_env()
        raise
    return outcome


def play_episode(env: gym.Env, agent: Any, spec: EpisodeSpec, recorder: Any = None) -> dict[str, Any]:
    """The benchmark's step loop: reset ``env`` with ``spec.seed`` and let ``agent`` act until the episode ends."""
    began = time.perf_counter()
    reset_options = BENCHMARK_RESET_OPTIONS.get(spec.task)
    observation, info = env.reset(seed=spec.seed, options=None if reset_options is None else reset_options(spec.seed))
    agent.reset(observation, info)
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
            recorder.caption = f"{spec.agent} / {spec.task}: {info['primitive']} -> {info['primitive_reason']}"
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
    }
    timing = {"wall_seconds": time.perf_counter() - began, "decision_seconds_median": float(np.median(decisions))}
    return {"result": result, "timing": timing}


def episode_failure(
    success: bool, terminated: bool, truncated: bool, info: dict[str, Any], out_of_steps: bool
) -> str | None:
    """Why an episode ended without success (None if it succeeded), from its last step's ``info``: the
    simulation diverged; a directional break toppled the tower the wrong way; a failed primitive knocked the
    tower over; a built tower fell; objects left the workspace; the step limit (``out_of_steps``) ran out;
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
    if out_of_steps:
        return "step_limit"
    return "gave_up" if truncated else "lost"


def wilson(successes: int, n: int, z: float = 1.96) -> list[float]:
    """95 % Wilson score interval."""
    return wilson_interval(successes / n, n, z) if n else [0.0, 1.0]


def wilson_interval(p: float, n: float, z: float = 1.96) -> list[float]:
    """Wilson score interval of a rate ``p`` observed over ``n`` (possibly effective, fractional) trials."""
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [round(max(0.0, float(centre - half)), 4), round(min(1.0, float(centre + half)), 4)]


def rate(successes: int, n: int) -> dict[str, Any]:
    return {"rate": round(successes / n, 4) if n else 0.0, "successes": successes, "n": n, "ci95": wilson(successes, n)}


def clustered_rate(successes: list[int], attempts: list[int]) -> dict[str, Any]:
    """A rate over attempts made in groups (grasps within episodes): the attempts of one episode are not
    independent (the same scene, the same policy), so the 95 % interval is Wilson's at the effective number
    of attempts -- n divided by the design effect, the cluster-robust variance of the ratio over the
    binomial one (never below 1: the interval is at least the per-attempt one)."""
    s, a = np.asarray(successes, dtype=float), np.asarray(attempts, dtype=float)
    total, n = int(s.sum()), int(a.sum())
    result = {**rate(total, n), "design_effect": 1.0}
    p, groups = (total / n if n else 0.0), int((a > 0).sum())
    if groups > 1 and 0.0 < p < 1.0:
        clustered = groups / (groups - 1) * float(((s - p * a) ** 2).sum()) / n**2
        design_effect = max(1.0, clustered / (p * (1 - p) / n))
        effective = n / design_effect
        result["ci95"] = wilson_interval(p, effective)
        result["design_effect"] = round(design_effect, 3)
    return result


def describe_rate(r: dict[str, Any]) -> str:
    """``rate`` / ``clustered_rate`` as text: "72.5 % (335/462, 95 % CI 68.3-76.4[, design effect 1.20])"."""
    low, high = r["ci95"]
    clustered = f", design effect {r['design_effect']:.2f}" if r.get("design_effect", 1.0) > 1.0 else ""
    return f"{100 * r['rate']:.1f} % ({r['successes']}/{r['n']}, 95 % CI {100 * low:.1f}-{100 * high:.1f}{clustered})"


def aggregate(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Metrics per ``agent/task`` from episode results (deterministic: no wall-clock figures)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault(f"{r['spec']['agent']}/{r['spec']['task']}", []).append(r)
    table = {}
    for key in sorted(groups):
        episodes = sorted(groups[key], key=lambda r: r["spec"]["seed"])
        n = len(episodes)
        actions = sum(r["actions"] for r in episodes)
        ideal_done = sum(r["ideal_actions"] for r in episodes if r["completion"])
        sim_hours = sum(r["sim_seconds"] for r in episodes) / 3600
        failures: Counter[str] = Counter()
        for r in episodes:
            failures.update(r["failures"])
        # An episode recorded before episodes named their failure counts as "unrecorded".
        why = Counter(r.get("failure", "unrecorded") for r in episodes if not r["success"])
        table[key] = {
            "episodes": n,
            "seeds": [r["spec"]["seed"] for r in episodes],
            "trial_success": rate(sum(r["success"] for r in episodes), n),
            "completion": rate(sum(r["completion"] for r in episodes), n),
            "grasp_success": clustered_rate(
                [r["grasps_succeeded"] for r in episodes], [r["grasps_attempted"] for r in episodes]
            ),
            "action_efficiency": round(ideal_done / actions, 4) if actions else 0.0,
            "cycles_per_sim_hour": round(sum(r["cycles"] for r in episodes) / sim_hours, 2) if sim_hours else 0.0,
            "failures": dict(sorted(failures.items())),
            "episode_failures": dict(sorted(why.items())),
            "sim_seconds_per_episode": round(sim_hours * 3600 / n, 3),
            "physics_errors": sum(r["physics_error"] for r in episodes),
            # Objects moved or tipped besides each primitive's targets, per action (see panda_grasp_env.sim.collateral).
            "collateral_per_action": round(sum(r.get("disturbed", 0) for r in episodes) / actions, 4)
            if actions
            else 0.0,
            "transit_contacts": sum(r.get("transit_contacts", 0) for r in episodes),
        }
        if any("first_grasp" in r for r in episodes):  # grasping tasks: episodes whose first grasp attempt held
            table[key]["first_grasp_success"] = rate(sum(r.get("first_grasp", False) for r in episodes), n)
    return table
