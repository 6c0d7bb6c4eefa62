"""Train from a config:  python train.py --config configs/<name>.yaml [key=value ...]

Policies (SB3: ``heightmap_dqn``, ``sac``, ``tqc``, ``ppo``, and from demonstrations ``bc``, ``tqc_demos``,
``heightmap_dqn_demos``; ``agents/learning/training.py``) or, with
``kind: fall_dynamics``, the falling-tower ConvLSTM (``panda_grasp_env/falls/training.py``).

Overrides use dotted keys into mappings (``algo_kwargs.learning_rate=3e-4``,
``env_kwargs.rotations=8``); values are read as YAML.  Every run writes one
folder under ``--runs`` (see ``agents/learning/training.py``); Ctrl-C checkpoints it, and
``--resume <run folder>`` continues it.  ``--seeds 0,1,2`` trains the config on each seed (in ``--workers``
local processes, or as Ray tasks with ``--ray ADDRESS``) and aggregates the runs' held-out figures with
rliable (IQM, stratified-bootstrap CIs, performance profiles) in a study folder
(``agents/learning/seed_runs.py``); ``--ship <study folder> --name N`` attaches it to checkpoint N's
card.  ``--ship <run folder> --name N`` copies
a finished run's model, card and curve to ``agents/checkpoints/N`` where
``panda_grasp_env.agents.policies.learned.LearnedAgent`` and ``evaluate.py`` find it (fall-dynamics runs:
``panda_grasp_env/falls/checkpoints/N``).  ``--retest <run or checkpoint folder>`` runs a policy's final
held-out test again (final.json, card.md), e.g. after the evaluation protocol or the physics changed;
on a fall-dynamics run or checkpoint it scores the model against the baselines on a recorded dataset's
test split (``dataset=PATH``, default its own; retest.json).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shutil
import sys
from pathlib import Path

import yaml

from panda_grasp_env.tooling.extras import learning_stack_problem

if learning_stack_problem("train.py") is not None:  # before the imports that need it: one line, no traceback
    print(f"error: {learning_stack_problem('train.py')}", file=sys.stderr)
    raise SystemExit(2)

# isort: split

from panda_grasp_env.agents.learning.config import check_policy_resume, config_from_dict, load_run, read_config
from panda_grasp_env.agents.learning.training import retest, start_run, train
from panda_grasp_env.agents.policies.policy_agent import ACTING_RULES
from panda_grasp_env.falls.config import FALL_RESUME_CHANGEABLE, fall_config
from panda_grasp_env.falls.training import start_fall_run, test_fall_model, train_fall_model
from panda_grasp_env.tooling.runs import (
    check_resume_changes,
    forget_failed_resume,
    interrupt_on_signals,
    record_resume,
    write_atomically,
)


def load_any(path: Path, overrides: list[str], source: str):
    """(config, kind) from a YAML file with overrides: a policy run or a fall-dynamics run."""
    raw = read_config(path, overrides)
    if raw.get("kind") == "fall_dynamics":
        return fall_config(raw, source), "fall_dynamics"
    return config_from_dict(raw, source), "policy"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, help="YAML training config (configs/)")
    parser.add_argument("overrides", nargs="*", help="key=value overrides of the config")
    parser.add_argument("--runs", type=Path, default=Path("runs"), help="folder that holds run folders")
    parser.add_argument("--resume", type=Path, default=None, help="continue this run folder")
    parser.add_argument("--ship", type=Path, default=None, help="copy this finished run to agents/checkpoints/--name")
    parser.add_argument("--name", default=None, help="checkpoint name for --ship")
    for rule, named in ACTING_RULES.items():
        parser.add_argument(
            f"--{rule.replace('_', '-')}",
            action="store_true",
            help=f"--ship: the checkpoint acts with {named.replace('`', '')} (agents/learning/acting_rules.py; "
            "decide on selection seeds)",
        )
    parser.add_argument("--retest", type=Path, default=None, help="test this run or checkpoint again")
    parser.add_argument(
        "--trust",
        action="store_true",
        help="with --resume: load latest.zip / replay.pkl / latest.pt even if this user's job did not "
        "sign them in this folder (a run copied or moved here)",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--seeds",
        default=None,
        help="with --config: train it on each of these comma-separated seeds and aggregate the "
        "runs (rliable) in runs/<name>-seeds-...",
    )
    parser.add_argument(
        "--workers",
        type=int,
        default=None,
        help="--seeds: local training processes (default: one per seed, at most the cores)",
    )
    parser.add_argument(
        "--ray",
        default=None,
        help="--seeds: train each seed as a Ray task on this cluster address ('local' starts one)",
    )
    args = parser.parse_args(argv)
    chosen = sum(x is not None for x in (args.config, args.resume, args.ship, args.retest))
    if chosen != 1:
        parser.error("give exactly one of --config, --resume, --ship or --retest")
    if args.ship is not None and not args.name:
        parser.error("--ship needs --name")
    if any(acting_rules(args).values()) and args.ship is None:
        parser.error("the acting rules' flags go with --ship")
    if args.trust and args.resume is None:
        parser.error("--trust goes with --resume")
    if (args.workers is not None or args.ray is not None) and args.seeds is None:
        parser.error("--workers and --ray go with --seeds")
    if args.seeds is not None:
        from panda_grasp_env.agents.learning.seed_runs import parse_seeds

        if args.config is None:
            parser.error("--seeds goes with --config")
        try:
            import rliable  # noqa: F401
        except ImportError:
            parser.error("--seeds aggregates with rliable: pip install -e '.[seeds]'")
        try:
            args.seeds = parse_seeds(args.seeds)
        except ValueError as error:
            parser.error(str(error))
        if args.workers is not None and args.workers < 1:
            parser.error(f"--workers must be >= 1, got {args.workers}")
        args.workers = args.workers or min(len(args.seeds), os.cpu_count() or 1)
        if args.ray is not None:
            try:
                import ray  # noqa: F401
            except ImportError:
                parser.error("--ray needs Ray: pip install -e '.[ray]'")
    return args


def acting_rules(args: argparse.Namespace) -> dict[str, bool]:
    """The acting rules the command line turns on, by name (``ACTING_RULES``)."""
    return {rule: getattr(args, rule) for rule in ACTING_RULES}


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    interrupt_on_signals()
    try:
        if args.ship is not None:
            if (args.ship / "study.json").is_file():  # a study over seeds: onto the checkpoint's card
                from panda_grasp_env.agents.learning.records import attach_study
                from panda_grasp_env.agents.policies.learned import CHECKPOINTS

                if not (CHECKPOINTS / args.name / "checkpoint.json").is_file():
                    raise ValueError(f"no shipped checkpoint {args.name!r} to attach {args.ship} to")
                print(f"attached to {attach_study(args.ship, CHECKPOINTS / args.name)}")
                return 0
            if (args.ship / "best.pt").exists():
                from panda_grasp_env.falls.records import ship_fall_run

                if any(acting_rules(args).values()):
                    raise ValueError("a fall-dynamics model acts by no rules (the acting rules' flags)")
                shipped = ship_fall_run(args.ship, args.name)
            else:
                from panda_grasp_env.agents.learning.records import ship

                shipped = ship(args.ship, args.name, **acting_rules(args))
            print(f"shipped to {shipped}")
            return 0
        if args.retest is not None:
            if (args.retest / "best.pt").is_file() or (args.retest / "model.pt").is_file():
                return retest_fall(args.retest, args.overrides)
            if args.overrides:
                raise ValueError(f"--retest of a policy takes no overrides, got {args.overrides}")
            return report(retest(args.retest), args.retest)
        if args.resume is not None:
            run_dir = args.resume
            if not (run_dir / "config.yaml").is_file():
                raise ValueError(f"{run_dir} is not a run folder (no config.yaml)")
            config, kind = load_any(run_dir / "config.yaml", args.overrides, str(run_dir / "config.yaml"))
            if kind == "policy":
                check_policy_resume(load_run(run_dir), config)
            else:
                saved, _ = load_any(run_dir / "config.yaml", [], str(run_dir / "config.yaml"))
                check_resume_changes(saved, config, FALL_RESUME_CHANGEABLE)
            if args.overrides:  # the run folder keeps the config it actually ran with
                write_atomically(run_dir / "config.yaml", yaml.safe_dump(dataclasses.asdict(config), sort_keys=False))
            latest = "latest.pt" if kind == "fall_dynamics" else "latest.zip"
            if not (run_dir / latest).exists():
                raise ValueError(f"{run_dir} has no checkpoint ({latest}) to resume from")
            record_resume(run_dir, args.overrides)
        else:
            config, kind = load_any(args.config, args.overrides, str(args.config))
            if args.seeds is not None:
                return train_over_seeds(config, kind, args)
            run_dir = start_fall_run(config, args.runs) if kind == "fall_dynamics" else start_run(config, args.runs)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:  # while the config or the run folder was read: nothing was trained
        if args.ship is not None or args.retest is not None:
            raise
        again = "the same command starts it" if args.resume is None else f"--resume {args.resume} continues it"
        print(f"\ninterrupted before training began: nothing was trained; {again}", file=sys.stderr)
        return 130
    print(f"run folder: {run_dir}")
    resume, progress = args.resume is not None, not args.no_progress
    try:
        if kind == "fall_dynamics":
            return report_fall(train_fall_model(config, run_dir, resume, progress, args.trust), run_dir)
        outcome = train(config, run_dir, resume=resume, progress_bar=progress, trust=args.trust)
    except KeyboardInterrupt:
        if any(run_dir.glob("latest.*")):
            print(
                f"\ninterrupted: checkpoint saved; continue with  python train.py --resume {run_dir}", file=sys.stderr
            )
        else:  # stopped while setting up, before the first checkpoint: a clean start, not a folder --resume refuses
            shutil.rmtree(run_dir, ignore_errors=True)
            print(
                f"\ninterrupted before the first checkpoint: nothing was saved and {run_dir} is removed; the same "
                "command starts the run again",
                file=sys.stderr,
            )
        return 130
    except ValueError as error:  # a new run that could not start (an init_policy of another network) leaves no folder
        if args.resume is None and not any(run_dir.glob("latest.*")):
            shutil.rmtree(run_dir)
        elif args.resume is not None:  # nor does a resumed session that could not start leave a record
            forget_failed_resume(run_dir)
        print(f"error: {error}", file=sys.stderr)
        return 2
    if outcome["stopped_by"] == "max_minutes":
        print(
            f"time budget spent at {outcome['steps']} steps; more with  python train.py --resume {run_dir} max_minutes=M"
        )
    return report(outcome, run_dir)


def train_over_seeds(config, kind: str, args: argparse.Namespace) -> int:
    """``--seeds``: the config trained on each seed, then the study folder's aggregate printed."""
    from panda_grasp_env.agents.learning.seed_runs import train_seeds

    if kind != "policy":
        raise ValueError("--seeds trains policies; a fall-dynamics config has one dataset split, not seeds")
    where = f"Ray tasks on {args.ray}" if args.ray else f"{args.workers} local process(es)"
    print(f"training {config.name} on seeds {args.seeds} in {where}; each run folder under {args.runs}")
    try:
        study = train_seeds(config, args.seeds, args.runs, args.workers, args.ray, not args.no_progress)
    except KeyboardInterrupt:
        print("\ninterrupted: finished and checkpointed runs are kept; the same command continues", file=sys.stderr)
        return 130
    print((study / "study.md").read_text())
    print(f"study: {study} (attach to a shipped checkpoint: python train.py --ship {study} --name NAME)")
    return 0


def report(outcome: dict, run_dir: Path) -> int:
    print(json.dumps({k: v for k, v in outcome.items() if k != "metrics"}, indent=2))
    metrics = outcome["metrics"]
    grasps = metrics["grasp_success"]  # none attempted in low-level (ee_delta) or tower-break episodes
    print(
        f"final: success {metrics['trial_success']['rate']:.3f} {metrics['trial_success']['ci95']}, "
        + (f"grasp success {grasps['rate']:.3f}, " if grasps["n"] else "")
        + f"efficiency {metrics['action_efficiency']:.3f} (N={metrics['episodes']}); card: {run_dir / 'card.md'}"
    )
    return 0


def print_fall_metrics(metrics: dict) -> None:
    for name, by_horizon in metrics.items():
        for horizon, m in by_horizon.items():
            print(
                f"{name:18s} {horizon}: mean block IoU {m['mean_block_iou']:.4f}, foreground accuracy "
                f"{m['foreground_accuracy']:.4f}, pixel accuracy {m['pixel_accuracy']:.4f} ({m['frames']} frames)"
            )


def print_fall_directions(direction: dict) -> None:
    """One line per predictor of ``fall_directions``' figures over all test towers."""
    print(
        f"fall direction: {direction['fell']} of {direction['sequences']} test towers fell, "
        f"{direction['hidden']} of them hidden in the first frame"
    )
    for name, d in direction["predictors"].items():
        if d["within_45"] is not None:
            print(
                f"{name:18s} within 45 degrees {d['within_45']:.3f}, median error {d['median_error_deg']:.1f} "
                f"degrees ({d['no_direction']} without a direction)"
            )


def report_fall(outcome: dict, run_dir: Path) -> int:
    if outcome["stopped_by"] == "max_minutes":
        print(f"time budget spent; more with  python train.py --resume {run_dir} max_minutes=M")
    print_fall_metrics(outcome["metrics"])
    print_fall_directions(outcome["direction"])
    print(f"card: {run_dir / 'card.md'}")
    return 0


def retest_fall(folder: Path, overrides: list[str]) -> int:
    """``--retest`` of a fall model: its test split, or another recorded dataset's with ``dataset=PATH``."""
    unknown = [o for o in overrides if not o.startswith("dataset=")]
    if unknown or len(overrides) > 1:
        raise ValueError(f"--retest of a fall model takes at most dataset=PATH, got {overrides}")
    result = test_fall_model(folder, overrides[0].partition("=")[2] if overrides else None)
    print(f"test split of {result['dataset']}: {result['test_sequences']} sequences")
    print_fall_metrics(result["metrics"])
    print_fall_directions(result["direction"])
    print(f"results: {folder / 'retest.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
