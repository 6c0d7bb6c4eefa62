"""Choose among finished runs (seeds of one recipe) on more validation episodes, never on the test seeds.

    python benchmarks/select_runs.py runs/<run A> runs/<run B> ... [--episodes 100]
                                     [--out results/benchmarks/select_runs.json] [--resume]

Each run's best validated policy (``best_policy.json`` + ``.safetensors``) plays ``--episodes`` episodes seeded
``eval_seed + SELECTION_SEED_OFFSET`` ... : past the periodic validation seeds (``eval_seed`` ...), far below
the final test's (``eval_seed + TEST_SEED_OFFSET`` ...).  A few validation episodes per evaluation pick a
run's best step; they are too few to rank runs against each other (a policy at 20/20 there can hold 88 %
of its test trials).  Prints each run's validation score (success, efficiency, grasp success) and the run
that ranks first.
"""

from __future__ import annotations

import argparse
import sys
from functools import partial
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

from benchmarks._common import Results, check_selection_episodes, policy_figures
from panda_grasp_env.agents.evaluation.metrics import describe_rate
from panda_grasp_env.agents.learning.config import load_run
from panda_grasp_env.agents.learning.records import load_best_policy
from panda_grasp_env.agents.learning.training import evaluate_on_selection_seeds, validation_score


def measure(run_dir: Path, episodes: int) -> dict:
    config = load_run(run_dir)
    policy, best = load_best_policy(run_dir)
    metrics = evaluate_on_selection_seeds(policy, config, episodes)
    return {"best_steps": best["steps"], **policy_figures(metrics)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("runs", type=Path, nargs="+", help="finished run folders (best.json, best_policy.json)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("results/benchmarks/select_runs.json"))
    parser.add_argument("--resume", action="store_true", help="keep the runs already measured in --out")
    args = parser.parse_args()
    check_selection_episodes(parser, args.episodes)
    for run_dir in args.runs:  # a wrong folder fails before anything runs
        if not (run_dir / "best.json").is_file():
            parser.error(f"{run_dir} has no best.json: not a finished run folder")
    results = Results(args.out, args.resume)
    scores = {}
    for run_dir in args.runs:
        row = results.section(str(run_dir), partial(measure, run_dir, args.episodes))
        scores[run_dir] = validation_score(row)
        print(
            f"{run_dir} (step {row['best_steps']}): success {describe_rate(row['trial_success'])}, efficiency "
            f"{100 * row['action_efficiency']:.1f} %, grasp success {describe_rate(row['grasp_success'])}; "
            f"{row['failures']}"
        )
    print(f"first on {args.episodes} selection episodes: {max(scores, key=scores.get)}")


if __name__ == "__main__":
    main()
