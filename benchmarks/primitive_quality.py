"""Quality of the simulation core's primitives, over seeded trials.

    python benchmarks/primitive_quality.py [--grasps 200] [--towers 100] [--pushes 50] [--resume]

* grasp on an isolated 5 cm cube at a random position and yaw (goal >= 98 %);
* reset towers standing 10 s untouched: drift (goal < 2 mm);
* the oracle (true poses + grasp/place primitives) building a 4-block tower
  from scattered blocks, yaw-aligned to the base (goal >= 95 %);
* a push aimed at a standing tower displacing >= 2 blocks by at least one block
  size from the footprint, per direction (goal >= 95 % each);
* determinism: the same seed and primitive sequence twice -> bit-identical state.

Rates are printed with a 95 % Wilson interval.  Results go to one JSON file,
saved atomically after each section; ``--resume`` skips finished sections.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("MUJOCO_GL", "egl")  # headless rendering; must precede the first mujoco import

import numpy as np  # noqa: E402

from benchmarks._common import Results, rate  # noqa: E402
from panda_grasp_env.agents.towers import build_tower, push_tower
from panda_grasp_env.model.scene import SceneConfig  # noqa: E402
from panda_grasp_env.primitives.top_down import grasp  # noqa: E402
from panda_grasp_env.sim.stacking import blocks_displaced, tower_footprint_centre  # noqa: E402
from panda_grasp_env.sim.workcell import Workcell  # noqa: E402
from panda_grasp_env.tasks.tower_break import BREAK_DIRECTIONS  # noqa: E402


def grasp_isolated(trials: int) -> dict:
    cell = Workcell(SceneConfig(n_blocks=1))
    reasons: Counter[str] = Counter()
    for seed in range(trials):
        cell.reset(np.random.default_rng(seed), "scattered")
        result = grasp(cell, *cell.block_positions()[0], float(cell.block_yaws()[0]))
        reasons[result.reason] += 1
    return rate(reasons["ok"], trials) | {"reasons": dict(reasons)}


def tower_drift(trials: int) -> dict:
    cell = Workcell()
    drifts = []
    for seed in range(trials):
        cell.reset(np.random.default_rng(seed), "tower")
        before = cell.block_positions()
        cell.wait(10.0)
        drifts.append(float(np.linalg.norm(cell.block_positions() - before, axis=1).max()))
    return {"n": trials, "max_drift_mm": 1000 * max(drifts), "median_drift_mm": 1000 * float(np.median(drifts))}


def oracle_towers(trials: int) -> dict:
    cell = Workcell()
    built, yaw_errors, actions, failures = 0, [], [], Counter()
    for seed in range(trials):
        cell.reset(np.random.default_rng(seed), "scattered")
        outcome = build_tower(cell)
        built += outcome.success
        actions.append(len(outcome.steps))
        if outcome.success:
            yaw_errors.append(outcome.max_yaw_error_deg)
        else:
            last = outcome.steps[-1]
            failures[f"{last.primitive}:{last.reason}" if not last.success else "misaligned"] += 1
    return rate(built, trials) | {
        "max_yaw_error_deg_median": float(np.median(yaw_errors)) if yaw_errors else None,
        "max_yaw_error_deg_worst": float(np.max(yaw_errors)) if yaw_errors else None,
        "mean_actions": float(np.mean(actions)),
        "failures": dict(failures),
    }


def pushes(trials: int) -> dict:
    cell = Workcell()
    figures = {}
    for offset, direction in enumerate(BREAK_DIRECTIONS):
        knocked, displaced_counts = 0, []
        for seed in range(trials):
            cell.reset(np.random.default_rng(10_000 * (offset + 1) + seed), "tower")
            centre = tower_footprint_centre(cell.block_positions())
            push_tower(cell, direction)
            cell.wait(1.0)
            displaced = blocks_displaced(cell.block_positions(), centre, cell.config.block_size)
            displaced_counts.append(displaced)
            knocked += displaced >= 2
        figures[direction] = rate(knocked, trials) | {"mean_blocks_displaced": float(np.mean(displaced_counts))}
    return figures


def determinism() -> dict:
    cell = Workcell()

    def run(seed: int) -> np.ndarray:
        cell.reset(np.random.default_rng(seed), "scattered")
        build_tower(cell)
        push_tower(cell, "+x")
        return np.concatenate([cell.data.qpos, cell.data.qvel]).copy()

    first, _, second = run(3), run(4), run(3)
    return {"bit_identical": bool(np.array_equal(first, second))}


def _fmt(r: dict) -> str:
    return f"{100 * r['rate']:6.1f} %  ({r['successes']}/{r['n']}, 95 % CI {100 * r['ci95'][0]:.1f}-{100 * r['ci95'][1]:.1f} %)"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--grasps", type=int, default=200)
    parser.add_argument("--towers", type=int, default=100)
    parser.add_argument("--drift", type=int, default=20)
    parser.add_argument("--pushes", type=int, default=50, help="trials per direction")
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/primitive_quality.json"))
    parser.add_argument("--resume", action="store_true", help="keep sections already in --out")
    args = parser.parse_args(argv)
    results = Results(args.out, args.resume)
    g = results.section("grasp_isolated_cube", lambda: grasp_isolated(args.grasps))
    print(f"grasp, isolated 5 cm cube:     {_fmt(g)}  reasons {g['reasons']}   (goal >= 98 %)")
    d = results.section("tower_drift_10s", lambda: tower_drift(args.drift))
    print(
        f"reset tower, 10 s untouched:   max drift {d['max_drift_mm']:.3f} mm, median {d['median_drift_mm']:.3f} mm over {d['n']}   (goal < 2 mm)"
    )
    t = results.section("oracle_tower_build", lambda: oracle_towers(args.towers))
    print(
        f"oracle 4-block tower:          {_fmt(t)}  mean actions {t['mean_actions']:.2f}, "
        f"yaw error median {t['max_yaw_error_deg_median']:.2f} deg worst {t['max_yaw_error_deg_worst']:.2f} deg, "
        f"failures {t['failures']}   (goal >= 95 %)"
    )
    p = results.section("push_tower", lambda: pushes(args.pushes))
    for direction, figures in p.items():
        print(
            f"push {direction} displaces >= 2:    {_fmt(figures)}  mean displaced {figures['mean_blocks_displaced']:.2f}   (goal >= 95 %)"
        )
    det = results.section("determinism", determinism)
    print(f"same seed -> bit-identical state: {det['bit_identical']}")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
