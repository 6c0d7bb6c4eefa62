"""Env steps per second against gymnasium-robotics' Fetch on the same MuJoCo, and how much of a step is physics.

    python benchmarks/env_throughput.py [--steps 3000] [--repeats 5] [--cross-version] [--panda-gym]
                                        [--out results/benchmarks/env_throughput.json] [--resume]

Every case runs ``--steps`` random actions through ``gymnasium.make`` (wrappers
included, and the resets when an episode ends) in a fresh process; each repeat
runs all cases one after the other, so machine noise hits them alike.  Ratios
are taken per repeat and their median is printed.

Same MuJoCo, this interpreter (the headline figures):

* ``ours_state``: ``PandaPush-v0``, ``ee_delta``, state observations;
* ``fetch_pick_state``, ``fetch_push_state``: ``FetchPickAndPlace-v4``, ``FetchPush-v4``;
* ``ours_rgbd``: ours with 84x84 RGB-D from the overhead camera every step (``obs_mode="state+rgbd"``);
* ``fetch_render``: ``FetchPickAndPlace-v4``, ``render_mode="rgb_array"`` at 84x84, ``render()`` every step.

gymnasium-robotics' joint helpers assert ``joint_type in (mjJNT_HINGE, mjJNT_SLIDE)``,
which MuJoCo >= 3.17's enum type no longer satisfies for numpy integers; the
worker patches that check at run time (``patch_fetch_joint_checks``), here only.

Besides steps per second each worker reports the physics: the wall time spent
inside ``mujoco.mj_step`` during the loop (timed by a wrapper around it, both
envs call it through the module) and the raw ``mj_step`` rate of the env's model
from its reset state with the controls held.  Two loop-efficiency figures follow:

* ``env rate / (raw rate / substeps)``: the issue's definition.  The raw rate is
  taken at rest, where contacts are cheaper than in a random-action loop, so this
  also charges the loop for physics that costs more in motion;
* ``physics share``: time inside ``mj_step`` / wall time, over the very states the
  loop visited (reset settling included): the part of the loop that is not Python.

Extra rows, each in its own virtual environment under ``.bench-venvs/`` (made on first use):

* ``--cross-version``: ``FetchPickAndPlace-v4`` on MuJoCo 3.3.7, what the project
  once compared against; that ratio measures MuJoCo versions as much as envs;
* ``--panda-gym``: panda-gym's ``PandaPush-v3`` (PyBullet; its reset and step as shipped).

Goals (issue 29): ours state >= 2x each Fetch state case; ours >= 0.70 of raw physics;
ours with RGB-D >= 3x Fetch rendering.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # benchmarks._physics, also in the workers
VENVS = ROOT / ".bench-venvs"
SAME_MUJOCO = ("ours_state", "fetch_pick_state", "fetch_push_state", "ours_rgbd", "fetch_render")
EXTRA = {
    "fetch_pick_mujoco337": ("fetch", lambda robotics: ["mujoco==3.3.7", f"gymnasium-robotics=={robotics}"]),
    "panda_gym_push": ("panda-gym", lambda robotics: ["panda-gym==3.0.7"]),
}
RAW_STEPS = 20_000


#: The gymnasium-robotics helpers that compare a joint type with ``mujoco.mjtJoint``, and the one line of
#: each that reads it.
FETCH_JOINT_HELPERS = ("get_joint_qpos", "get_joint_qvel", "set_joint_qpos", "set_joint_qvel")
JOINT_TYPE_READ = "joint_type = model.jnt_type[joint_id]"


def patch_fetch_joint_checks() -> None:
    """Let gymnasium-robotics' joint helpers run on MuJoCo >= 3.17 (see the module docstring), changing nothing
    else: each of ``FETCH_JOINT_HELPERS`` is recompiled from its own source with its joint-type read cast to
    ``int``; every other function, and every ``mujoco.X`` lookup, stays gymnasium-robotics' own.  (A proxy
    in place of the module's ``mujoco`` served every lookup through ``__getattr__`` and cost Fetch ~18 %.)"""
    import inspect
    import textwrap

    from gymnasium_robotics.utils import mujoco_utils

    for name in FETCH_JOINT_HELPERS:
        helper = getattr(mujoco_utils, name)
        if getattr(helper, "joint_type_cast", False):
            continue
        source = textwrap.dedent(inspect.getsource(helper))
        if source.count(JOINT_TYPE_READ) != 1:
            raise RuntimeError(f"gymnasium-robotics' {name} no longer reads {JOINT_TYPE_READ!r}: review the patch")
        source = source.replace(JOINT_TYPE_READ, "joint_type = int(model.jnt_type[joint_id])")
        namespace: dict[str, Any] = {}
        exec(compile(source, inspect.getsourcefile(helper) or name, "exec"), mujoco_utils.__dict__, namespace)
        patched = namespace[name]
        patched.joint_type_cast = True
        setattr(mujoco_utils, name, patched)


def make_env(case: str) -> tuple[Any, Any, Any, int]:
    """(env, its MjModel, its MjData, physics steps per env step) for a MuJoCo case."""
    import gymnasium as gym

    if case.startswith("ours"):
        obs_mode = "state+rgbd" if case == "ours_rgbd" else "state"
        env = gym.make("panda_grasp_env:PandaPush-v0", action_mode="ee_delta", obs_mode=obs_mode, image_size=(84, 84))
        cell = env.unwrapped.cell
        return env, cell.model, cell.data, cell.physics.control_substeps
    import gymnasium_robotics

    gym.register_envs(gymnasium_robotics)
    if not case.endswith("mujoco337"):
        patch_fetch_joint_checks()
    kwargs = {"render_mode": "rgb_array", "width": 84, "height": 84} if case == "fetch_render" else {}
    env = gym.make("FetchPush-v4" if case == "fetch_push_state" else "FetchPickAndPlace-v4", **kwargs)
    return env, env.unwrapped.model, env.unwrapped.data, env.unwrapped.n_substeps


def measure(case: str, steps: int, seed: int = 0) -> dict[str, float]:
    """One case in this interpreter: env steps/s, and the physics figures (see the module docstring)."""
    import numpy as np

    import panda_grasp_env  # noqa: F401  (it chooses MUJOCO_GL before mujoco is imported)

    if case == "panda_gym_push":
        return measure_panda_gym(steps, seed)
    from benchmarks._physics import raw_step_rate, timed_mj_step

    env, model, data, substeps = make_env(case)
    render = case == "fetch_render"
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, *env.action_space.shape)).astype(np.float32)
    env.reset(seed=seed)
    for action in actions[:50]:  # warm-up: first renders, caches
        env.step(action)
        if render:
            env.render()
    env.reset(seed=seed)
    raw = raw_step_rate(model, data, RAW_STEPS)
    with timed_mj_step() as physics:
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if render:
                env.render()
            if terminated or truncated:
                env.reset()
        wall = time.perf_counter() - start
    env.close()
    rate = steps / wall
    return {
        "rate": rate,
        "raw_rate": raw,
        "substeps": substeps,
        "loop_efficiency": rate / (raw / substeps),
        "physics_share": physics.seconds / wall,
        "physics_steps_per_step": physics.steps / steps,
    }


def measure_panda_gym(steps: int, seed: int) -> dict[str, float]:
    """panda-gym's ``PandaPush-v3`` (PyBullet): steps/s only."""
    import gymnasium as gym
    import numpy as np
    import panda_gym  # noqa: F401  (registers the ids)

    env = gym.make("PandaPush-v3")
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, *env.action_space.shape)).astype(np.float32)
    env.reset(seed=seed)
    for action in actions[:50]:
        env.step(action)
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return {"rate": rate}


def extra_python(case: str) -> str:
    """The interpreter of an extra row's own virtual environment (created on first use)."""
    from importlib.metadata import version

    folder, packages = EXTRA[case]
    python = VENVS / folder / "bin" / "python"
    if not python.exists():
        wanted = packages(version("gymnasium-robotics"))
        print(f"creating {VENVS / folder} ({', '.join(wanted)}) ...")
        subprocess.run([sys.executable, "-m", "venv", str(VENVS / folder)], check=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", *wanted], check=True)
    return str(python)


def run_case(case: str, steps: int) -> dict[str, float]:
    """Measure a case in a fresh process (extra rows in their own venvs, the rest in this one)."""
    interpreter = extra_python(case) if case in EXTRA else sys.executable
    command = [interpreter, __file__, "--worker", case, "--steps", str(steps)]
    out = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--cross-version", action="store_true", help="add Fetch on MuJoCo 3.3.7 (its own venv)")
    parser.add_argument("--panda-gym", action="store_true", help="add panda-gym's PandaPush-v3 (its own venv)")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "env_throughput.json")
    parser.add_argument("--resume", action="store_true", help="keep repeats already saved in --out")
    parser.add_argument("--worker", choices=(*SAME_MUJOCO, *EXTRA), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.steps < 100 or args.repeats < 1:
        raise ValueError(f"--steps must be >= 100 and --repeats >= 1, got {args.steps} and {args.repeats}")
    if args.worker:
        print(json.dumps(measure(args.worker, args.steps)))
        return

    from benchmarks._common import Results

    cases = [*SAME_MUJOCO]
    cases += ["fetch_pick_mujoco337"] if args.cross_version else []
    cases += ["panda_gym_push"] if args.panda_gym else []
    results = Results(args.out, args.resume)
    repeats = []
    for repeat in range(args.repeats):
        figures = results.section(f"repeat_{repeat}", lambda: {case: run_case(case, args.steps) for case in cases})
        repeats.append(figures)
        ratios = {
            "pick": figures["ours_state"]["rate"] / figures["fetch_pick_state"]["rate"],
            "push": figures["ours_state"]["rate"] / figures["fetch_push_state"]["rate"],
            "render": figures["ours_rgbd"]["rate"] / figures["fetch_render"]["rate"],
        }
        print(
            f"repeat {repeat}: "
            + "  ".join(f"{case} {figures[case]['rate']:6.0f}/s" for case in cases)
            + "  | ours / "
            + "  ".join(f"{name} {ratio:.2f}x" for name, ratio in ratios.items())
        )

    def median(case: str, key: str) -> float:
        return statistics.median(r[case][key] for r in repeats)

    def ratio(ours: str, theirs: str) -> float:
        return statistics.median(r[ours]["rate"] / r[theirs]["rate"] for r in repeats)

    summary = {
        "median_rate": {case: median(case, "rate") for case in cases},
        "ratio_fetch_pick": ratio("ours_state", "fetch_pick_state"),
        "ratio_fetch_push": ratio("ours_state", "fetch_push_state"),
        "ratio_render": ratio("ours_rgbd", "fetch_render"),
        "loop_efficiency": {case: median(case, "loop_efficiency") for case in SAME_MUJOCO},
        "physics_share": {case: median(case, "physics_share") for case in SAME_MUJOCO},
        "raw_rate": {case: median(case, "raw_rate") for case in SAME_MUJOCO},
    }
    print(f"\nmedians of {args.repeats} repeats x {args.steps} random steps ({results.data['machine']})")
    print(f"{'case':26s} {'steps/s':>8s} {'raw mj_step/s':>14s} {'rate/(raw/substeps)':>20s} {'physics share':>14s}")
    for case in SAME_MUJOCO:
        print(
            f"{case:26s} {summary['median_rate'][case]:8.0f} {summary['raw_rate'][case]:14.0f} "
            f"{summary['loop_efficiency'][case]:20.2f} {summary['physics_share'][case]:14.2f}"
        )
    for case in cases[len(SAME_MUJOCO) :]:
        label = "(MuJoCo 3.3.7, other versions)" if case == "fetch_pick_mujoco337" else "(PyBullet)"
        summary[f"ratio_{case}"] = ratio("ours_state", case)
        print(
            f"{case:26s} {summary['median_rate'][case]:8.0f}   ours state / it {summary[f'ratio_{case}']:.2f}x  {label}"
        )
    print(f"\nours state / FetchPickAndPlace state, same MuJoCo  {summary['ratio_fetch_pick']:.2f}x  (goal >= 2)")
    print(f"ours state / FetchPush state, same MuJoCo          {summary['ratio_fetch_push']:.2f}x  (goal >= 2)")
    print(f"ours RGB-D 84 / Fetch render 84, same MuJoCo       {summary['ratio_render']:.2f}x  (goal >= 3)")
    print(
        f"ours rate / (raw / substeps)                      {summary['loop_efficiency']['ours_state']:.2f}   (goal >= 0.70)"
    )
    print(f"ours physics share (same states)                  {summary['physics_share']['ours_state']:.2f}")
    results.data.pop("summary", None)  # recomputed from the repeats every run
    results.section("summary", lambda: summary)


if __name__ == "__main__":
    main()
