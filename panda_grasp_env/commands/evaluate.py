"""Main job: benchmark agents against each other on every task, through the same env.step loop.

    python evaluate.py                      # quick benchmark (<= 10 minutes on 2 cores)
    python evaluate.py --full               # the publication protocol (30 clutter runs, 100 tower trials, ...)
    python evaluate.py --agents planned,random --tasks TowerBuild --seeds 20 --workers 2
    python evaluate.py --tasks GraspClutter --seed-list 5000,5001,5002 --task-options n_objects=1
                                            # any seeds, any env/task options (a held-out protocol)
    python evaluate.py --config protocol.yaml   # the same from one file (agents, tasks, seeds, options)
    python evaluate.py --import my_lab.shelf --tasks Shelf   # tasks and agents registered outside the package
    python evaluate.py --resume             # finish an interrupted run without redoing episodes
    python evaluate.py --demo [--seed 0]    # the simulation-core demo: an oracle builds and breaks a tower
    python evaluate.py compare RUN_A RUN_B  # did a change matter? tested differences per (agent, task)

Agents: random, planned (perception-based planned baselines), oracle (the same, on
true poses), expert (scripted ee_delta state machines for Lift, Push and Stack), and every shipped
learned checkpoint by name (agents/checkpoints/): on its own task, and on the other scenes of that
task its observation and action spaces fit (a heightmap grasping policy on heaps and packed layouts);
and build_and_break_dqn, BuildAndBreak played by the shipped builder and breaker, each in its phase
(``panda_grasp_env.agents.policies.phased``).
Tasks: the benchmarks evaluation declares (``panda_grasp_env.agents.evaluation.benchmarks``): Grasp,
GraspClutter, GraspAdversarial, TowerBuild, TowerBreak, TowerBreakDirectional, BuildAndBreak, PutInBin (primitive actions),
Push, Lift, Stack (low-level ee_delta); played only when named: the mesh benchmarks (GraspMesh*) and the towers
of 6 and 8 blocks (TowerBuild6, TowerBuild8, TowerBreak6, ..., BuildAndBreak8).  An agent that does not apply to a task is skipped (one line counts them;
the reports give each pair and reason).
Outputs (``--out``, default results/quick or results/full): results.json and
results.csv (deterministic: same seeds give identical files), timing.json,
report.md, report.html (one static page: heatmap, charts, failures, decision times, clips, protocol;
``commands/results_page.py``), success.png, failures.png and one MP4 per (agent, task).
This module is the command line; the protocol, the runner and the report are ``panda_grasp_env.agents.evaluation``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS, default_benchmarks
from panda_grasp_env.agents.evaluation.episodes import close_kept_env
from panda_grasp_env.agents.evaluation.protocol import (
    RunProtocol,
    all_agents,
    baseline,
    import_modules,
    task_options_from_pairs,
)
from panda_grasp_env.agents.evaluation.report import results_table, videos, write_report, write_results
from panda_grasp_env.agents.evaluation.runner import run_episodes
from panda_grasp_env.agents.policies.towers import build_tower, push_tower, through_env
from panda_grasp_env.commands.results_figures import save_pngs
from panda_grasp_env.commands.results_page import write_page
from panda_grasp_env.sim.stacking import blocks_displaced, tower_footprint_centre
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_yaml
from panda_grasp_env.tooling.runs import interrupt_on_signals
from panda_grasp_env.tooling.video import VideoRecorder

#: The demo's env: its primitives are grasp, place and push, and the script gives the heights.
DEMO_ENV = "panda_grasp_env:PandaBuildAndBreak-v0"


def demo(args: argparse.Namespace) -> int:
    """An oracle builds a 4-block tower with grasp and place primitives and pushes it over, every primitive an
    ``env.step`` of ``DEMO_ENV`` (MP4 + summary)."""
    args.out.mkdir(parents=True, exist_ok=True)
    env = gym.make(DEMO_ENV, action_mode="primitive", primitive_z=True, push_distance=0.16)
    env.reset(seed=args.seed)
    cell, act = env.unwrapped.cell, through_env(env)
    recorder = None if args.no_video else VideoRecorder(cell, args.out / "demo.mp4", width=640, height=480)
    start = time.perf_counter()
    try:
        if recorder:
            recorder.caption = "build: oracle grasp + place"
        build = build_tower(cell, act)
        for step in build.steps:
            print(f"  {step.primitive:6s} {step.object or '':13s} {step.reason:12s} {step.sim_time:5.2f} s simulated")
        print(f"tower built: {build.success} (max yaw error {build.max_yaw_error_deg:.2f} deg)")
        centre = tower_footprint_centre(cell.block_positions())
        if recorder:
            recorder.caption = f"break: push {args.push}"
        push_result = push_tower(cell, act, args.push)
        cell.wait(1.5)  # the blocks come to rest before they are counted: no action, the scene alone
        displaced = blocks_displaced(cell.block_positions(), centre, cell.config.block_size)
        print(f"push {args.push}: {push_result.reason}, {displaced} blocks displaced")
    finally:
        if recorder:
            video = recorder.save()
            print(f"video: {video} ({recorder.frames_written} frames)")
        env.close()
    summary = {
        "seed": args.seed,
        "tower_built": build.success,
        "max_yaw_error_deg": build.max_yaw_error_deg,
        "primitives": [{"primitive": s.primitive, "reason": s.reason, "object": s.object} for s in build.steps],
        "push": {"direction": args.push, "reason": push_result.reason, "blocks_displaced": displaced},
        "simulated_s": cell.sim_time,
        "wall_s": time.perf_counter() - start,
    }
    tmp = args.out / "summary.json.tmp"
    tmp.write_text(json.dumps(summary, indent=2))
    tmp.replace(args.out / "summary.json")
    print(f"simulated {cell.sim_time:.1f} s in {summary['wall_s']:.1f} s wall; summary: {args.out / 'summary.json'}")
    return 0 if build.success and displaced >= 2 else 1


#: The most episodes one (agent, task) pair may play in a run: ``--seeds`` and ``--seed-list`` are bounded
#: before any episode spec is made.
MAX_SEEDS = 100_000
#: ``--config`` file keys and the flags they stand for: a protocol (who plays what, on which seeds, with which
#: options) in one YAML file.
PROTOCOL_KEYS = {
    "agents": "--agents",
    "tasks": "--tasks",
    "full": "--full",
    "seeds": "--seeds",
    "seed_start": "--seed-start",
    "seed_list": "--seed-list",
    "task_options": "--task-options",
    "import": "--import",
}


def protocol_argv(path: Path) -> list[str]:
    """The flags a ``--config`` protocol file stands for; ``ValueError`` naming a bad key or value."""
    raw = read_yaml(path, MAX_DOCUMENT_BYTES)
    if not isinstance(raw, dict):
        raise ValueError(f"protocol file {path} must be a mapping of {list(PROTOCOL_KEYS)}")
    unknown = [k for k in raw if k not in PROTOCOL_KEYS]
    if unknown:
        raise ValueError(f"unknown key(s) {unknown} in {path}; valid: {list(PROTOCOL_KEYS)}")
    argv: list[str] = []
    for key, value in raw.items():
        flag = PROTOCOL_KEYS[key]
        if key == "full":
            if not isinstance(value, bool):
                raise ValueError(f"{path}: full must be true or false, got {value!r}")
            argv += [flag] if value else []
        elif key == "task_options":
            if not isinstance(value, dict) or not value:
                raise ValueError(f"{path}: task_options must be a non-empty mapping, got {value!r}")
            argv += [flag, *(f"{k}={json.dumps(v)}" for k, v in value.items())]  # JSON is YAML
        elif key == "import":
            modules = [value] if isinstance(value, str) else value
            if not isinstance(modules, list) or not modules or not all(isinstance(m, str) and m for m in modules):
                raise ValueError(f"{path}: import must be a module name or a list of them, got {value!r}")
            argv += [part for module in modules for part in (flag, module)]
        elif isinstance(value, list):
            argv += [flag, ",".join(map(str, value))]
        else:
            argv += [flag, str(value)]
    return argv


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    argv = sys.argv[1:] if argv is None else list(argv)
    if "--config" in argv:  # the file's flags first: flags given on the command line after it win
        at = argv.index("--config")
        try:
            if at + 1 == len(argv):
                raise ValueError("--config needs a protocol file")
            argv = protocol_argv(Path(argv[at + 1])) + argv[:at] + argv[at + 2 :]
        except ValueError as error:
            print(f"error: {error}", file=sys.stderr)
            raise SystemExit(2) from None
    imports = argparse.ArgumentParser(add_help=False)
    imports.add_argument("--import", action="append", default=[], dest="imports")
    modules = imports.parse_known_args(argv)[0].imports
    tasks_before, agents_before = set(BENCHMARKS), set(all_agents())
    try:  # before the choices of agents and tasks are listed: the modules add to them
        import_modules(modules)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    epilog = None
    if modules:  # --help says what they registered
        new_tasks = [t for t in BENCHMARKS if t not in tasks_before]
        new_agents = [a for a in all_agents() if a not in agents_before]
        planned_on = [t for t in new_tasks if baseline(t) is not None]
        new_agents += [f"planned and oracle on {', '.join(planned_on)}"] if planned_on else []
        epilog = f"Registered by --import {', '.join(modules)}: tasks {new_tasks}; agents {new_agents}."
    if "--seed-list" in argv[:-1]:  # argparse reads "--seed-list -1,2" as a flag without its value
        at = argv.index("--seed-list")
        if argv[at + 1][:2].lstrip("-").isdigit() and argv[at + 1].startswith("-"):
            argv[at : at + 2] = [f"--seed-list={argv[at + 1]}"]  # the seeds then reach their own check
    parser = argparse.ArgumentParser(
        description=__doc__, epilog=epilog, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help=f"a YAML protocol file with keys {list(PROTOCOL_KEYS)} (command-line flags win)",
    )
    parser.add_argument(
        "--import",
        action="append",
        default=[],
        dest="imports",
        metavar="MODULE",
        help="import a module (a dotted name, or a .py file) that registers tasks and agents; "
        "repeatable; worker processes import it too",
    )
    parser.add_argument("--full", action="store_true", help="the publication protocol instead of the quick one")
    agents = all_agents()
    parser.add_argument("--agents", default=",".join(agents), help=f"comma-separated, from {list(agents)}")
    parser.add_argument(
        "--tasks",
        default=",".join(default_benchmarks()),
        help=f"comma-separated, from {list(BENCHMARKS)} (default: all but the mesh benchmarks, "
        "which need the objects extra, and the 6- and 8-block towers)",
    )
    parser.add_argument(
        "--seeds", type=int, default=None, help="episodes per (agent, task): seeds --seed-start .. --seed-start + N - 1"
    )
    parser.add_argument("--seed-start", type=int, default=0, help="the first seed (default 0)")
    parser.add_argument("--seed-list", default=None, help="comma-separated seeds, instead of --seeds / --seed-start")
    parser.add_argument(
        "--task-options",
        nargs="+",
        default=[],
        metavar="KEY=VALUE",
        help="gymnasium.make options for every chosen task, values in YAML (n_objects=1, "
        "scene options, obs/action modes for learned agents ...)",
    )
    parser.add_argument("--workers", type=int, default=1, help="parallel worker processes")
    parser.add_argument(
        "--ray", default=None, help="run episodes as Ray tasks: a cluster address, 'auto', or 'local' to start one here"
    )
    parser.add_argument("--out", type=Path, default=None, help="results folder")
    parser.add_argument("--resume", action="store_true", help="keep finished episodes in --out, run the rest")
    parser.add_argument("--no-video", action="store_true", help="skip the MP4s")
    parser.add_argument("--demo", action="store_true", help="run the simulation-core demo instead")
    parser.add_argument("--seed", type=int, default=0, help="(demo) seed of the block layout")
    parser.add_argument("--push", default="+y", choices=["+x", "+y", "-x", "-y"], help="(demo) push direction")
    args = parser.parse_args(argv)
    for name, valid in (("agents", agents), ("tasks", BENCHMARKS)):
        chosen = [v for v in getattr(args, name).split(",") if v]
        unknown = [v for v in chosen if v not in valid]
        if unknown or not chosen:
            parser.error(f"unknown {name} {unknown or chosen}; valid: {list(valid)}")
        setattr(args, name, chosen)
    if args.workers < 1 or (args.seeds is not None and not 1 <= args.seeds <= MAX_SEEDS) or args.seed_start < 0:
        parser.error(f"--workers must be positive, --seeds in [1, {MAX_SEEDS}], --seed-start >= 0")
    args.seed_list = parse_seed_list(parser, args)
    args.task_options = parse_task_options(parser, args.task_options, args.tasks)
    if args.ray is not None:
        try:
            import ray  # noqa: F401
        except ImportError:
            parser.error("--ray needs Ray: pip install -e '.[ray]'")
    if args.out is None:
        args.out = Path("results/demo" if args.demo else "results/full" if args.full else "results/quick")
    args.protocol = RunProtocol(
        agents=tuple(args.agents),
        tasks=tuple(args.tasks),
        full=args.full,
        seeds=args.seeds,
        seed_start=args.seed_start,
        seed_list=None if args.seed_list is None else tuple(args.seed_list),
        task_options=args.task_options,
        imports=tuple(args.imports),
    )
    return args


def parse_seed_list(parser: argparse.ArgumentParser, args: argparse.Namespace) -> list[int] | None:
    """``--seed-list`` as distinct non-negative ints (None without it); it excludes ``--seeds``/``--seed-start``."""
    if args.seed_list is None:
        return None
    if args.seeds is not None or args.seed_start:
        parser.error("--seed-list replaces --seeds and --seed-start: give one or the other")
    try:
        seeds = [int(s) for s in args.seed_list.split(",") if s.strip()]
    except ValueError:
        parser.error(f"--seed-list must be comma-separated integers, got {args.seed_list!r}")
    if not seeds or min(seeds) < 0 or len(set(seeds)) < len(seeds) or len(seeds) > MAX_SEEDS:
        parser.error(f"--seed-list must hold distinct seeds >= 0, at most {MAX_SEEDS}, got {args.seed_list[:80]!r}")
    return seeds


def parse_task_options(parser: argparse.ArgumentParser, pairs: list[str], tasks: list[str]) -> dict[str, Any]:
    """``--task-options KEY=VALUE ...`` as a mapping (``evaluation.task_options_from_pairs``); errors stop the parser."""
    try:
        return task_options_from_pairs(pairs, tasks)
    except ValueError as error:
        parser.error(str(error))


def prepare_out(out: Path) -> None:
    """Make the results folder ``out`` and check that files can be written in it; ``ValueError`` saying why not."""
    import tempfile

    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as error:
        raise ValueError(f"--out {out}: cannot write results there ({error.strerror or error})") from None


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["compare"]:  # evaluate.py compare RUN_A RUN_B
        from panda_grasp_env.commands.compare import main as compare

        return compare(argv[1:])
    args = parse_args(argv)
    interrupt_on_signals()
    try:
        prepare_out(args.out)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if args.demo:
        return demo(args)
    protocol = args.protocol
    # A checkpoint that cannot load (or would need trust: panda_grasp_env.agents.policies.learned.Checkpoint) stops
    # the run before any episode.
    try:
        for checkpoint in protocol.checkpoints():
            checkpoint.load_policy()
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    specs, skipped = protocol.episode_specs()
    if skipped:  # the pairs and their reasons are in the report
        print(f"skipped {len(skipped)} agent/task pairs that do not apply (which and why: {args.out / 'report.html'})")
    if not specs:
        reasons = sorted(set(skipped.values()))
        print(f"nothing to run: no chosen agent applies to a chosen task ({'; '.join(reasons[:3])})", file=sys.stderr)
        return 2
    started = time.perf_counter()
    try:
        log = args.out / "episodes.jsonl"
        records = run_episodes(
            specs,
            log,
            resume=args.resume,
            workers=args.workers,
            ray_address=args.ray,
            imports=protocol.imports,
            videos=None if args.no_video else args.out,
        )
    except KeyboardInterrupt:
        return 130
    except ValueError as error:  # a --resume record refused: before any episode ran
        print(f"error: {error}", file=sys.stderr)
        return 2
    summary = write_results(records, protocol, skipped, args.out)
    table_md = results_table(summary)
    print(table_md)
    save_pngs(summary["table"], args.out)
    try:  # filmed while played; only a clip that is missing (a resumed run's) replays its episode
        video_paths = [] if args.no_video else videos(specs, args.out)
    finally:
        close_kept_env()
    write_report(args.out, protocol, skipped, table_md, video_paths, args.workers)
    page = write_page(args.out)
    print(f"{len(specs)} episodes in {time.perf_counter() - started:.0f} s; report: {args.out / 'report.md'}, {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
