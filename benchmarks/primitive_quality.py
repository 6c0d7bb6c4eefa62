"""Quality of the simulation core's primitives, over seeded trials.

    python benchmarks/primitive_quality.py [--grasps 200] [--towers 100] [--pushes 50] [--resume]

* grasp on an isolated 5 cm cube at a random position and yaw (goal >= 98 %);
* reset towers standing 10 s untouched: drift (goal < 2 mm);
* the oracle (true poses + grasp/place primitives) building a 4-block tower
  from scattered blocks, yaw-aligned to the base (goal >= 95 %);
* a push aimed at a standing tower displacing >= 2 blocks by at least one block
  size from the footprint, per direction (goal >= 95 % each);
* a 20 cm push of one block from a random spot, heading and yaw: stalls, error across the stroke, how close
  the hand comes to the stroke's end, the block's tilt and springback, the hand's turn during the stroke;
* determinism: the same seed and primitive sequence twice -> bit-identical state.

Rates are printed with a 95 % Wilson interval.  Results go to one JSON file,
saved atomically after each section; ``--resume`` skips finished sections.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import numpy as np  # noqa: E402

from benchmarks._common import Results, rate  # noqa: E402
from panda_grasp_env.agents.policies.towers import build_tower, on_workcell, push_tower  # noqa: E402
from panda_grasp_env.control.controller import wrap_gripper_yaw  # noqa: E402
from panda_grasp_env.geometry import yaw_quaternion  # noqa: E402
from panda_grasp_env.model.scene import SceneConfig  # noqa: E402
from panda_grasp_env.primitives.parameters import PrimitiveSettings  # noqa: E402
from panda_grasp_env.primitives.registry import Aim  # noqa: E402
from panda_grasp_env.primitives.top_down import grasp, push  # noqa: E402
from panda_grasp_env.sim.motion import WORKSPACE  # noqa: E402
from panda_grasp_env.sim.stacking import blocks_displaced, tower_footprint_centre  # noqa: E402
from panda_grasp_env.sim.workcell import SPAWN_REGION, Workcell  # noqa: E402
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
        outcome = build_tower(cell, on_workcell(cell))
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
            push_tower(cell, on_workcell(cell), direction)
            cell.wait(1.0)
            displaced = blocks_displaced(cell.block_positions(), centre, cell.config.block_size)
            displaced_counts.append(displaced)
            knocked += displaced >= 2
        figures[direction] = rate(knocked, trials) | {"mean_blocks_displaced": float(np.mean(displaced_counts))}
    return figures


def watched_push(cell: Workcell, block: int, start: np.ndarray, z: float, heading: float, distance: float) -> dict:
    """One push of ``block`` from ``start`` (x, y) at height ``z``, watched: the figures of ``push_precision``."""
    along = np.array([np.cos(heading), np.sin(heading), 0.0])
    end = np.array([*(start[:2] + distance * along[:2]), z])
    before = cell.data.xpos[block].copy()
    stroke: dict = {"on": False, "tilt": 0.0, "yaws": [], "end_error": None, "block_at_end": None}
    move_to = cell.motion.move_to

    def watched_move(position: np.ndarray, yaw: float, **options: object) -> object:
        stroke["on"] = bool(np.allclose(np.asarray(position)[:2], end[:2], atol=0.01))  # the stroke, corrections too
        outcome = move_to(position, yaw, **options)
        if stroke["on"]:
            stroke["end_error"] = float(np.linalg.norm((cell.robot.ee_position - end)[:2]))
            stroke["block_at_end"] = cell.data.xpos[block].copy()
        stroke["on"] = False
        return outcome

    def watch(cell: Workcell) -> None:
        if stroke["on"]:
            stroke["tilt"] = max(stroke["tilt"], float(np.arccos(np.clip(cell.data.xmat[block][8], -1, 1))))
            stroke["yaws"].append(cell.robot.ee_yaw)

    cell.motion.move_to = watched_move
    cell.physics.add_observer(watch)
    try:
        result = push(cell, *start[:2], z, heading, distance)
    finally:
        del cell.motion.move_to
        cell.physics.remove_observer(watch)
    moved = cell.data.xpos[block] - before
    grip_heading = heading + np.pi / 2
    return {
        "reason": result.reason,
        "along_mm": 1e3 * float(moved @ along),
        "lateral_mm": 1e3 * float(moved @ [-along[1], along[0], 0.0]),
        "end_error_mm": None if stroke["end_error"] is None else 1e3 * stroke["end_error"],
        "tilt_deg": float(np.degrees(stroke["tilt"])),
        "springback_mm": None
        if stroke["block_at_end"] is None
        else 1e3 * float((stroke["block_at_end"] - cell.data.xpos[block]) @ along),
        "hand_turn_deg": float(np.degrees(np.ptp(np.unwrap(stroke["yaws"])))) if stroke["yaws"] else 0.0,
        # Where the heading's half-turn branch at the start and at the end differ (by a half turn).
        "crosses_joint7_window": bool(
            abs(wrap_gripper_yaw(grip_heading, start) - wrap_gripper_yaw(grip_heading, end)) > np.pi / 2
        ),
    }


def push_precision(trials: int, scene: SceneConfig, distance: float = 0.2, gap: float = 0.06) -> dict:
    """Pushes of one block: a 5 cm cube at a random spot and yaw of the spawn region, pushed ``distance`` metres
    along a random heading from ``gap`` behind its centre at the automatic push height.  Per trial: how far
    the block moved along the stroke and across it, how close the hand came to the stroke's end (horizontally),
    the block's largest tilt during the stroke, how far it sprang back after, and how far the hand turned."""
    cell = Workcell(replace(scene, n_blocks=1))
    block = int(cell.block_ids[0])
    settings = PrimitiveSettings(primitives=("push",), push_distance=distance)
    rows = []
    for seed in range(trials):
        rng = np.random.default_rng(20_000 + seed)
        while True:  # a stroke inside the workspace
            centre, yaw, heading = rng.uniform(*SPAWN_REGION.T), rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi, np.pi)
            start = centre - gap * np.array([np.cos(heading), np.sin(heading)])
            end = start + distance * np.array([np.cos(heading), np.sin(heading)])
            if all(np.all((p >= WORKSPACE[:2, 0]) & (p <= WORKSPACE[:2, 1])) for p in (start, end)):
                break
        cell.clear()
        cell.set_body_pose(block, np.array([*centre, cell.config.block_size / 2]), yaw_quaternion(yaw))
        cell.settle(0.2)
        z = Aim("push", *start, heading).parameters(cell, settings).z
        rows.append(watched_push(cell, block, start, z, heading, distance))
    # The block should end up the stroke less the gap, plus the block's and the fingers' half thickness ahead.
    expected = 1e3 * (distance - gap + cell.config.block_size / 2)
    keys = ("lateral_mm", "end_error_mm", "tilt_deg", "springback_mm", "hand_turn_deg")

    def values(key: str) -> list[float]:
        return [abs(row[key]) for row in rows if row[key] is not None] or [float("nan")]

    return {
        "n": trials,
        "stalled": rate(sum(row["along_mm"] < 0.5 * expected for row in rows), trials),
        "lateral_within_10mm": rate(sum(abs(row["lateral_mm"]) <= 10 for row in rows), trials),
        "end_within_2mm": rate(
            sum(row["end_error_mm"] is not None and row["end_error_mm"] <= 2 for row in rows), trials
        ),
        "crossing_trials": sum(row["crosses_joint7_window"] for row in rows),
        **{f"median_{key}": float(np.median(values(key))) for key in keys},
        **{f"worst_{key}": float(np.max(values(key))) for key in keys},
        "reasons": dict(Counter(row["reason"] for row in rows)),
        "rows": rows,
    }


def determinism() -> dict:
    cell = Workcell()

    def run(seed: int) -> np.ndarray:
        cell.reset(np.random.default_rng(seed), "scattered")
        build_tower(cell, on_workcell(cell))
        push_tower(cell, on_workcell(cell), "+x")
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
    parser.add_argument("--push-trials", type=int, default=100, help="single-block pushes (push precision)")
    parser.add_argument("--stiff-contacts", action="store_true", help="push precision with stiff world contacts")
    parser.add_argument("--push-faces", action="store_true", help="push precision with the fingers' push faces")
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
    scene = SceneConfig(stiff_contacts=args.stiff_contacts, push_faces=args.push_faces)
    q = results.section("push_precision", lambda: push_precision(args.push_trials, scene))
    print(
        f"push one block 20 cm:          stalled {_fmt(q['stalled'])}; lateral <= 1 cm {_fmt(q['lateral_within_10mm'])}; "
        f"hand within 2 mm of the stroke's end {_fmt(q['end_within_2mm'])}"
    )
    print(
        "                               median / worst: "
        + ", ".join(
            f"{key} {q['median_' + key]:.1f} / {q['worst_' + key]:.1f}"
            for key in ("lateral_mm", "end_error_mm", "tilt_deg", "springback_mm", "hand_turn_deg")
        )
        + f"; {q['crossing_trials']} strokes cross a joint-7 window edge; reasons {q['reasons']}"
    )
    det = results.section("determinism", determinism)
    print(f"same seed -> bit-identical state: {det['bit_identical']}")
    print(f"saved {args.out}")


if __name__ == "__main__":
    main()
