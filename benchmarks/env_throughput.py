"""Env steps per second, side by side with gymnasium-robotics' FetchPickAndPlace-v4, in one run.

    python benchmarks/env_throughput.py [--steps 3000] [--repeats 5] [--fetch-python PATH]
                                        [--out results/benchmarks/env_throughput.json] [--resume]

Four figures, each the median of ``--repeats`` runs of ``--steps`` random-action
steps through ``gymnasium.make`` (wrappers included, resets included when an
episode ends), measured in alternation so machine noise hits all alike:

* ours: ``PandaPush-v0``, ``ee_delta``, state observations;
* ours: the same with 84x84 RGB-D from the overhead camera every step (``obs_mode="state+rgbd"``);
* Fetch: ``FetchPickAndPlace-v4`` state only;
* Fetch: the same with ``render_mode="rgb_array"`` at 84x84, ``render()`` every step.

gymnasium-robotics' Fetch envs fail on MuJoCo >= 3.17 (a joint-type check), so
Fetch runs in its own virtual environment (``.bench-venvs/fetch``: MuJoCo 3.3.7
and the installed gymnasium-robotics version), created on first use unless
``--fetch-python`` names an interpreter that has them.
Goals (issue 3): ours state-only >= 2x Fetch state-only; ours with RGB-D >= 3x Fetch rendering.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FETCH_VENV = ROOT / ".bench-venvs" / "fetch"
FETCH_MUJOCO = "3.3.7"
CASES = ("ours_state", "fetch_state", "ours_rgbd", "fetch_render")


def measure(case: str, steps: int, seed: int = 0) -> float:
    """Steps per second of one case, in this interpreter."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    import gymnasium as gym
    import numpy as np

    render = case == "fetch_render"
    if case.startswith("fetch"):
        import gymnasium_robotics

        gym.register_envs(gymnasium_robotics)
        kwargs = {"render_mode": "rgb_array", "width": 84, "height": 84} if render else {}
        env = gym.make("FetchPickAndPlace-v4", **kwargs)
    else:
        obs_mode = "state+rgbd" if case == "ours_rgbd" else "state"
        env = gym.make("panda_grasp_env:PandaPush-v0", action_mode="ee_delta", obs_mode=obs_mode, image_size=(84, 84))
    actions = np.random.default_rng(seed).uniform(-1.0, 1.0, (steps, *env.action_space.shape)).astype(np.float32)
    env.reset(seed=seed)
    for action in actions[:50]:  # warm-up: first renders, caches
        env.step(action)
        if render:
            env.render()
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if render:
            env.render()
        if terminated or truncated:
            env.reset()
    rate = steps / (time.perf_counter() - start)
    env.close()
    return rate


def fetch_python(given: str | None) -> str:
    """An interpreter that can run Fetch: ``given``, or the benchmark's own venv (created if missing)."""
    if given:
        return given
    python = FETCH_VENV / "bin" / "python"
    if not python.exists():
        from importlib.metadata import version

        print(
            f"creating {FETCH_VENV} (mujoco=={FETCH_MUJOCO}, gymnasium-robotics=={version('gymnasium-robotics')}) ..."
        )
        subprocess.run([sys.executable, "-m", "venv", str(FETCH_VENV)], check=True)
        packages = [f"mujoco=={FETCH_MUJOCO}", f"gymnasium-robotics=={version('gymnasium-robotics')}"]
        subprocess.run([str(python), "-m", "pip", "install", "-q", *packages], check=True)
    return str(python)


def run_case(case: str, steps: int, python: str) -> float:
    """Measure a case in a fresh process (Fetch in its own venv, ours in this one)."""
    interpreter = python if case.startswith("fetch") else sys.executable
    command = [interpreter, __file__, "--worker", case, "--steps", str(steps)]
    out = subprocess.run(command, check=True, capture_output=True, text=True, cwd=ROOT)
    return float(json.loads(out.stdout.strip().splitlines()[-1])["rate"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--fetch-python", default=None, help="interpreter with gymnasium-robotics and MuJoCo 3.3")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "benchmarks" / "env_throughput.json")
    parser.add_argument("--resume", action="store_true", help="keep repeats already saved in --out")
    parser.add_argument("--worker", choices=CASES, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps({"rate": measure(args.worker, args.steps)}))
        return

    sys.path.insert(0, str(ROOT))
    from benchmarks._common import Results

    python = fetch_python(args.fetch_python)
    results = Results(args.out, args.resume)
    for repeat in range(args.repeats):
        figures = results.section(
            f"repeat_{repeat}", lambda: {case: run_case(case, args.steps, python) for case in CASES}
        )
        print(f"repeat {repeat}: " + "  ".join(f"{case} {rate:7.0f}/s" for case, rate in figures.items()))
    repeats = [results.data[f"repeat_{r}"] for r in range(args.repeats)]
    median = {case: statistics.median(r[case] for r in repeats) for case in CASES}
    state_ratio = statistics.median(r["ours_state"] / r["fetch_state"] for r in repeats)
    render_ratio = statistics.median(r["ours_rgbd"] / r["fetch_render"] for r in repeats)
    print(f"\nenv steps per second, median of {args.repeats} x {args.steps} steps ({results.data['machine']})")
    print(f"  ours ee_delta, state            {median['ours_state']:7.0f}")
    print(f"  Fetch PickAndPlace, state       {median['fetch_state']:7.0f}   ratio {state_ratio:.2f}x  (goal >= 2x)")
    print(f"  ours ee_delta, state + RGB-D 84 {median['ours_rgbd']:7.0f}")
    print(f"  Fetch PickAndPlace, render 84   {median['fetch_render']:7.0f}   ratio {render_ratio:.2f}x  (goal >= 3x)")
    results.section("summary", lambda: {"median": median, "state_ratio": state_ratio, "render_ratio": render_ratio})


if __name__ == "__main__":
    main()
