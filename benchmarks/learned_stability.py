"""Does the learned fall model know what stands?  Its verdicts on the lookahead planner's candidate places,
scored against the simulator's.

    python benchmarks/learned_stability.py [--candidates 500] [--seed-start 7000] [--tiers 2,3,4]
        [--fall-model fall_convlstm_structures,fall_convlstm_structures_settle] [--resume]

``planned_lookahead`` builds random structures of the generator (``structure="random"``, the training
distribution: never the named suite) on seeds ``seed-start`` onwards.  Before each choice, every target still
to build is a candidate: ready ones (their supports stand) and the rest (set in the air over what is missing).
Each is judged twice on the same state: by the simulator (``sim.stability.what_if``, which the episode follows) and
by each shipped fall model named (``learned_physics.FallModelCheck``: one rendered frame, the model's planned
block displacements), so that models are compared on the same candidates.  The planner itself acts on the simulator's verdicts.  A candidate that falls is a positive.  Prints the share that falls, the model's precision
and recall at the shipped threshold, the same over thresholds picked on the first half of the seeds and
scored on the second, and the check's median time.  Candidates are appended per episode to
``results/learned_stability/candidates.jsonl`` (``--resume`` keeps the episodes done).

``--dataset data/falls_structures_...`` judges instead the test split (seed % 10 == 9) of a recorded
structure-fall dataset (``python -m panda_grasp_env.falls --scene structures``): each sequence's first frame
is the candidate, and it falls where a piece moves ``STILL_SHIFT`` (4 mm) or more over the sequence.  With
``--shifted-candidates`` recordings this scores ready places that tip, which the planner's candidates on the
generator's structures never hold; datasets recorded since 2026-12-07 store each candidate's kind (in the air,
ready, shifted), and each kind is also scored alone.  ``--fall-model`` takes shipped names or ``model.pt``/``best.pt`` paths.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import gymnasium as gym
import numpy as np
import torch

from panda_grasp_env.agents.evaluation.benchmarks import STRUCTURE_OPTIONS
from panda_grasp_env.agents.evaluation.episodes import play_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
from panda_grasp_env.agents.learning.falls.dataset import load_split
from panda_grasp_env.agents.learning.falls.settling import classification, largest_shifts
from panda_grasp_env.agents.policies.learned_physics import DEFAULT_FALL_MODEL, DEFAULT_THRESHOLD, FallModelCheck
from panda_grasp_env.agents.policies.structure_views import HeightmapPieces, Seen
from panda_grasp_env.agents.policies.structures import StructurePlanner
from panda_grasp_env.falls.structure_falls import CANDIDATE_KINDS
from panda_grasp_env.sim.stability import STILL_SHIFT, what_if

OUT = Path("results/learned_stability")


class RecordingCheck:
    """The simulator's what-if (whose verdict the planner follows), with each fall model's beside it while
    ``recording``."""

    def __init__(self, learned: dict[str, FallModelCheck]) -> None:
        self.learned, self.rows, self.recording, self.ready = learned, [], True, True

    def __call__(self, model, data, moves, watched):  # noqa: ANN001, ANN204  (what_if's signature)
        truth = what_if(model, data, moves, watched)
        if not self.recording:
            return truth
        predicted, seconds = {}, {}
        for name, check in self.learned.items():
            began = time.perf_counter()
            predicted[name] = check(model, data, moves, watched).shift
            seconds[name] = time.perf_counter() - began
        self.rows.append(
            {"falls": not truth.stands, "ready": self.ready, "sim_shift": truth.shift, "sim_turn": truth.turn,
             "predicted_shift": predicted, "seconds": seconds}
        )  # fmt: skip
        return truth


class EveryCandidate(StructurePlanner):
    """The lookahead planner that checks, before each choice, every target still to build, not only the ready
    ones up to the first that stands: candidates that stand and candidates that fall."""

    def _choose(self, ready: list[int], seen: Seen) -> int | None:
        for index in np.flatnonzero(~seen.filled):
            self.check.ready = int(index) in ready
            self._stands(int(index), seen, [])
        self.check.recording = False
        try:
            return super()._choose(ready, seen)
        finally:
            self.check.recording = True


def play(seed: int, tiers: list[int], check: RecordingCheck) -> list[dict]:
    env = gym.make("panda_grasp_env:PandaStructure-v0", structure="random", tiers=tiers, **STRUCTURE_OPTIONS)
    try:
        planner = EveryCandidate(HeightmapPieces(), lookahead=True, env=env, check=check)
        check.rows = []
        outcome = play_episode(env, planner, EpisodeSpec("planned_lookahead", "Structure", seed, ()))
    finally:
        env.close()
    return [{**row, "seed": seed, "success": outcome["result"]["success"]} for row in check.rows]


def scores(rows: list[dict], name: str, threshold: float) -> dict[str, float]:
    """Precision and recall of "falls" (model ``name``'s predicted shift >= threshold, metres) against the
    simulator, and accuracy."""
    predicted = np.array([r["predicted_shift"][name] for r in rows])
    return {"threshold": threshold, **classification(predicted, np.array([r["falls"] for r in rows]), threshold)}


def best_threshold(rows: list[dict], name: str) -> float:
    """The threshold of greatest balanced accuracy on ``rows`` (each of model ``name``'s predicted shifts tried)."""
    falls = np.array([r["falls"] for r in rows])
    shifts = np.array([r["predicted_shift"][name] for r in rows])
    if falls.all() or not falls.any():
        return DEFAULT_THRESHOLD
    candidates = np.unique(shifts)
    balanced = [0.5 * (np.mean(shifts[falls] >= t) + np.mean(shifts[~falls] < t)) for t in candidates]
    return float(candidates[int(np.argmax(balanced))])


def dataset_rows(root: Path, checks: dict[str, FallModelCheck]) -> list[dict]:
    """The test split of a structure-fall dataset as candidates (module doc), each model's planned shift
    (metres, at the depth of the crop's centre) from the first frame."""
    split = load_split(root, "test", depth=True)
    focal = float(np.asarray(split.camera["K"])[0][0])
    moved = largest_shifts(split, split.poses.shape[1] - 1)
    kinds = [None] * len(moved) if split.candidate_kind is None else [CANDIDATE_KINDS[k] for k in split.candidate_kind]
    rows = []
    for labels, depth, n, seed, shift, kind in zip(
        split.labels, split.depth, split.n_blocks, split.seeds, moved, kinds
    ):
        first = labels[0].astype(np.int64)
        metres_per_pixel = float(depth[0][first.shape[0] // 2, first.shape[1] // 2]) / focal
        predicted = {
            name: check.largest_shift(first, depth[0].astype(np.float32), int(n), metres_per_pixel)
            for name, check in checks.items()
        }
        rows.append(
            {"falls": bool(shift >= STILL_SHIFT), "seed": int(seed), "kind": kind, "predicted_shift": predicted}
        )
    return rows


def line(name: str, figures: dict[str, float]) -> str:
    return (
        f"{name:<34} threshold {figures['threshold'] * 1000:7.2f} mm  precision {figures['precision']:.3f}  "
        f"recall {figures['recall']:.3f}  accuracy {figures['accuracy']:.3f}  said falls {figures['said_falls']}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--candidates", type=int, default=500)
    parser.add_argument("--seed-start", type=int, default=7000)
    parser.add_argument("--tiers", default="2,3,4")
    parser.add_argument(
        "--fall-model",
        default=f"fall_convlstm_structures,{DEFAULT_FALL_MODEL}",
        help="shipped fall models or model.pt/best.pt paths, comma-separated (judged side by side)",
    )
    parser.add_argument("--resume", action="store_true")
    parser.add_argument("--dataset", type=Path, default=None, help="judge a structure-fall dataset's test split")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.dataset is not None:
        names = args.fall_model.split(",")
        rows = dataset_rows(args.dataset, {name: FallModelCheck(name) for name in names})
        print(f"{len(rows)} test sequences of {args.dataset}: {sum(r['falls'] for r in rows)} fall")
        for name in names:
            print(f"\nfall model {name}")
            print(line("all, shipped threshold", scores(rows, name, DEFAULT_THRESHOLD)))
            for kind in CANDIDATE_KINDS:  # recorded since 2026-12-07
                if group := [r for r in rows if r["kind"] == kind]:
                    falls = sum(r["falls"] for r in group)
                    print(line(f"{kind} ({len(group)}, {falls} fall)", scores(group, name, DEFAULT_THRESHOLD)))
            print(line("best balanced threshold (in-sample)", scores(rows, name, best_threshold(rows, name))))
        return
    tiers = [int(t) for t in args.tiers.split(",")]
    OUT.mkdir(parents=True, exist_ok=True)
    path = OUT / "candidates.jsonl"
    names = args.fall_model.split(",")
    rows = [json.loads(text) for text in path.read_text().splitlines()] if args.resume and path.exists() else []
    if any(set(r["predicted_shift"]) != set(names) for r in rows):
        raise ValueError(f"--resume: {path} was recorded with other fall models than --fall-model {args.fall_model}")
    if not args.resume:
        path.write_text("")
    check = RecordingCheck({name: FallModelCheck(name) for name in names})
    seed = max((r["seed"] for r in rows), default=args.seed_start - 1) + 1
    while len(rows) < args.candidates:
        played = play(seed, tiers, check)
        with path.open("a") as file:  # one whole episode a write: an interrupted run resumes after it
            file.write("".join(json.dumps(row) + "\n" for row in played))
        rows += played
        print(f"seed {seed}: {len(played)} candidates, {sum(r['falls'] for r in played)} fall ({len(rows)} in all)")
        seed += 1
    seeds = sorted({r["seed"] for r in rows})
    calibration = [r for r in rows if r["seed"] in seeds[: len(seeds) // 2]]
    held_out = [r for r in rows if r["seed"] in seeds[len(seeds) // 2 :]]
    falls = sum(r["falls"] for r in rows)
    print(f"\n{len(rows)} candidate places on seeds {seeds[0]}-{seeds[-1]} (tiers {args.tiers}): {falls} fall")
    ready = [r for r in rows if r["ready"]]
    print(f"ready candidates (supports standing): {len(ready)}, {sum(r['falls'] for r in ready)} fall")
    for name in names:
        print(f"\nfall model {name}; check median {statistics.median(r['seconds'][name] for r in rows) * 1000:.0f} ms")
        print(line("all, shipped threshold", scores(rows, name, DEFAULT_THRESHOLD)))
        print(line("ready, shipped threshold", scores(ready, name, DEFAULT_THRESHOLD)))
        picked = best_threshold(calibration, name)
        print(f"threshold picked on seeds {seeds[0]}-{seeds[len(seeds) // 2 - 1]} ({len(calibration)} candidates)")
        print(line("held-out half, picked threshold", scores(held_out, name, picked)))
        for label, group in (("falls", True), ("stands", False)):
            shifts = [r["predicted_shift"][name] * 1000 for r in rows if r["falls"] == group]
            if shifts:
                q = np.percentile(shifts, [10, 50, 90])
                print(f"predicted shift where the simulator says {label}: p10 {q[0]:.2f}  median {q[1]:.2f}  "
                      f"p90 {q[2]:.2f} mm")  # fmt: skip


if __name__ == "__main__":
    main()
