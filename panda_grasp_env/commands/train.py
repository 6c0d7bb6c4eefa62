"""Train from a config:  python train.py --config configs/<name>.yaml [key=value ...]

Policies (SB3: ``heightmap_dqn``, ``sac``, ``tqc``, ``ppo``, and from demonstrations ``bc``, ``tqc_demos``,
``heightmap_dqn_demos``; ``agents/learning/training.py``) or, with
``kind: fall_dynamics``, the falling-tower ConvLSTM (``agents/learning/falls/training.py``).  The kind a
config declares (a policy's declares none) picks what each step below does (``commands/run_kinds.py``); a
run folder and a shipped checkpoint declare theirs in their config.yaml, a study in its study.json.

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
``agents/learning/falls/checkpoints/N``).  ``--retest <run or checkpoint folder>`` runs a policy's final
held-out test again (final.json, card.md), e.g. after the evaluation protocol or the physics changed;
on a fall-dynamics run or checkpoint it scores the model against the baselines on a recorded dataset's
test split (``dataset=PATH``, default its own; retest.json).
"""

from __future__ import annotations

import argparse
import dataclasses
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

from panda_grasp_env.agents.learning.config import read_config
from panda_grasp_env.agents.policies.policy_agent import ACTING_RULES
from panda_grasp_env.commands.run_kinds import folder_kind, load_run_config, run_kind
from panda_grasp_env.tooling.runs import forget_failed_resume, interrupt_on_signals, record_resume, write_atomically


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
            holds, kind = folder_kind(args.ship)
            if holds == "study":  # a study over seeds: onto the checkpoint's card
                print(f"attached to {kind.attach_study(args.ship, args.name)}")
            else:
                print(f"shipped to {kind.ship(args.ship, args.name, acting_rules(args))}")
            return 0
        if args.retest is not None:
            return run_kind(args.retest).retest(args.retest, args.overrides)
        if args.resume is not None:
            run_dir = args.resume
            kind, saved_config = run_kind(run_dir), run_dir / "config.yaml"
            config = kind.config(read_config(saved_config, args.overrides), str(saved_config))
            kind.check_resume(kind.config(read_config(saved_config), str(saved_config)), config)
            if args.overrides:  # the run folder keeps the config it actually ran with
                write_atomically(saved_config, yaml.safe_dump(dataclasses.asdict(config), sort_keys=False))
            if not (run_dir / kind.latest).exists():
                raise ValueError(f"{run_dir} has no checkpoint ({kind.latest}) to resume from")
            record_resume(run_dir, args.overrides)
        else:
            config, kind = load_run_config(args.config, args.overrides, str(args.config))
            if args.seeds is not None:
                return kind.train_seeds(config, args.seeds, args.runs, args.workers, args.ray, not args.no_progress)
            run_dir = kind.start(config, args.runs)
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
        outcome = kind.train(config, run_dir, resume, progress, args.trust)
    except KeyboardInterrupt:
        if (run_dir / kind.latest).exists():
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
        if args.resume is None and not (run_dir / kind.latest).exists():
            shutil.rmtree(run_dir)
        elif args.resume is not None:  # nor does a resumed session that could not start leave a record
            forget_failed_resume(run_dir)
        print(f"error: {error}", file=sys.stderr)
        return 2
    return kind.report(outcome, run_dir)


if __name__ == "__main__":
    sys.exit(main())
