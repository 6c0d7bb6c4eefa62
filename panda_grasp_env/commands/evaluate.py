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
(``panda_grasp_env.agents.phased``).
Tasks: the benchmarks the task modules register (``panda_grasp_env.registration.BENCHMARKS``): Grasp,
GraspClutter, GraspAdversarial, TowerBuild, TowerBreak, TowerBreakDirectional, BuildAndBreak, PutInBin (primitive actions),
Push, Lift, Stack (low-level ee_delta); played only when named: the mesh benchmarks (GraspMesh*) and the towers
of 6 and 8 blocks (TowerBuild6, TowerBuild8, TowerBreak6, ..., BuildAndBreak8).  An agent that does not apply to a task is skipped (one line counts them;
the reports give each pair and reason).
Outputs (``--out``, default results/quick or results/full): results.json and
results.csv (deterministic: same seeds give identical files), timing.json,
report.md, report.html (one static page: heatmap, charts, failures, decision times, clips, protocol;
``commands/results_page.py``), success.png, failures.png and one MP4 per (agent, task).
"""

from __future__ import annotations

import argparse
import io
import json
import multiprocessing
import os
import sys
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation import (
    AGENTS,
    EpisodeSpec,
    aggregate,
    all_agents,
    close_kept_env,
    import_modules,
    is_low_level,
    run_episode,
    skip_reason,
    task_options_from_pairs,
)
from panda_grasp_env.agents.towers import build_tower, push_tower
from panda_grasp_env.commands.results_page import describe_seeds, save_pngs, write_page
from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.registration import BENCHMARK_SEEDS, BENCHMARKS, DEFAULT_BENCHMARKS
from panda_grasp_env.sim.stacking import blocks_displaced, tower_footprint_centre
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tooling.runs import commit, interrupt_on_signals, machine, versions, write_atomically
from panda_grasp_env.tooling.video import VideoRecorder


def demo(args: argparse.Namespace) -> int:
    """An oracle builds a 4-block tower with grasp and place primitives and pushes it over (MP4 + summary)."""
    args.out.mkdir(parents=True, exist_ok=True)
    cell = Workcell()
    cell.reset(np.random.default_rng(args.seed), "scattered")
    recorder = None if args.no_video else VideoRecorder(cell, camera="front", width=640, height=480)
    start = time.perf_counter()
    try:
        if recorder:
            recorder.caption = "build: oracle grasp + place"
        build = build_tower(cell)
        for step in build.steps:
            print(f"  {step.primitive:6s} {step.object or '':13s} {step.reason:12s} {step.sim_time:5.2f} s simulated")
        print(f"tower built: {build.success} (max yaw error {build.max_yaw_error_deg:.2f} deg)")
        centre = tower_footprint_centre(cell.block_positions())
        if recorder:
            recorder.caption = f"break: push {args.push}"
        push_result = push_tower(cell, args.push)
        cell.wait(1.5)
        displaced = blocks_displaced(cell.block_positions(), centre, cell.config.block_size)
        print(f"push {args.push}: {push_result.reason}, {displaced} blocks displaced")
    finally:
        if recorder:
            video = recorder.save(args.out / "demo.mp4")
            print(f"video: {video} ({recorder.frames_written} frames)")
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


#: ``--config`` file keys and the flags they stand for: a protocol (who plays what, on which seeds, with which
#: options) in one YAML file.
PROTOCOL_KEYS = {"agents": "--agents", "tasks": "--tasks", "full": "--full", "seeds": "--seeds",
                 "seed_start": "--seed-start", "seed_list": "--seed-list", "task_options": "--task-options",
                 "import": "--import"}  # fmt: skip


def protocol_argv(path: Path) -> list[str]:
    """The flags a ``--config`` protocol file stands for; ``ValueError`` naming a bad key or value."""
    import yaml

    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as error:
        raise ValueError(f"cannot read protocol file {path}: {error}") from None
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
    try:  # before the choices of agents and tasks are listed: the modules add to them
        import_modules(imports.parse_known_args(argv)[0].imports)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    if "--seed-list" in argv[:-1]:  # argparse reads "--seed-list -1,2" as a flag without its value
        at = argv.index("--seed-list")
        if argv[at + 1][:2].lstrip("-").isdigit() and argv[at + 1].startswith("-"):
            argv[at : at + 2] = [f"--seed-list={argv[at + 1]}"]  # the seeds then reach their own check
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=None,
                        help=f"a YAML protocol file with keys {list(PROTOCOL_KEYS)} (command-line flags win)")  # fmt: skip
    parser.add_argument("--import", action="append", default=[], dest="imports", metavar="MODULE",
                        help="import a module (a dotted name, or a .py file) that registers tasks and agents; "
                             "repeatable; worker processes import it too")  # fmt: skip
    parser.add_argument("--full", action="store_true", help="the publication protocol instead of the quick one")
    agents = all_agents()
    parser.add_argument("--agents", default=",".join(agents), help=f"comma-separated, from {list(agents)}")
    parser.add_argument("--tasks", default=",".join(DEFAULT_BENCHMARKS),
                        help=f"comma-separated, from {list(BENCHMARKS)} (default: all but the mesh benchmarks, "
                             "which need the objects extra, and the 6- and 8-block towers)")  # fmt: skip
    parser.add_argument("--seeds", type=int, default=None,
                        help="episodes per (agent, task): seeds --seed-start .. --seed-start + N - 1")  # fmt: skip
    parser.add_argument("--seed-start", type=int, default=0, help="the first seed (default 0)")
    parser.add_argument("--seed-list", default=None, help="comma-separated seeds, instead of --seeds / --seed-start")
    parser.add_argument("--task-options", nargs="+", default=[], metavar="KEY=VALUE",
                        help="gymnasium.make options for every chosen task, values in YAML (n_objects=1, "
                             "scene options, obs/action modes for learned agents ...)")  # fmt: skip
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
    if args.workers < 1 or (args.seeds is not None and args.seeds < 1) or args.seed_start < 0:
        parser.error("--workers and --seeds must be positive, --seed-start >= 0")
    args.seed_list = parse_seed_list(parser, args)
    args.task_options = parse_task_options(parser, args.task_options, args.tasks)
    if args.ray is not None:
        try:
            import ray  # noqa: F401
        except ImportError:
            parser.error("--ray needs Ray: pip install -e '.[ray]'")
    args.skipped = {}
    if args.out is None:
        args.out = Path("results/demo" if args.demo else "results/full" if args.full else "results/quick")
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
    if not seeds or min(seeds) < 0 or len(set(seeds)) < len(seeds):
        parser.error(f"--seed-list must hold distinct seeds >= 0, got {args.seed_list!r}")
    return seeds


def parse_task_options(parser: argparse.ArgumentParser, pairs: list[str], tasks: list[str]) -> dict[str, Any]:
    """``--task-options KEY=VALUE ...`` as a mapping (``evaluation.task_options_from_pairs``); errors stop the parser."""
    try:
        return task_options_from_pairs(pairs, tasks)
    except ValueError as error:
        parser.error(str(error))


def chosen_seeds(args: argparse.Namespace, task: str) -> list[int]:
    """The seeds each (agent, ``task``) pair plays: ``--seed-list``, else ``--seeds`` (or the protocol's count)
    from ``--seed-start``."""
    if args.seed_list is not None:
        return list(args.seed_list)
    count = args.seeds or BENCHMARK_SEEDS[task][1 if args.full else 0]
    return list(range(args.seed_start, args.seed_start + count))


def episode_specs(args: argparse.Namespace) -> list[EpisodeSpec]:
    """The episodes to run; (agent, task) pairs that do not apply are reported and left out."""
    options = tuple(sorted(args.task_options.items()))
    specs = []
    for task in args.tasks:
        for agent in args.agents:
            reason = skip_reason(agent, task)
            if reason is not None:
                args.skipped[f"{agent}/{task}"] = reason
                continue
            specs.extend(EpisodeSpec(agent, task, seed, options) for seed in chosen_seeds(args, task))
    return specs


def _append(path: Path, record: dict) -> None:
    """One finished episode per line, flushed to disk at once (an interrupted run keeps it)."""
    with path.open("a") as handle:
        handle.write(json.dumps(record, sort_keys=True) + "\n")
        handle.flush()
        os.fsync(handle.fileno())


#: An episode record's ``result`` fields and their JSON types (``run_episode`` writes them; ``--resume`` checks).
RESULT_FIELDS: dict[str, type | tuple[type, ...]] = {
    "spec": dict, "success": bool, "completion": bool, "actions": int, "ideal_actions": int,
    "grasps_attempted": int, "grasps_succeeded": int, "cycles": int, "sim_seconds": (int, float),
    "failures": dict, "physics_error": bool, "disturbed": int, "transit_contacts": int,
}  # fmt: skip
#: Fields only some results hold: grasping tasks' ``first_grasp``, mesh episodes' object ids (``meshes``).
OPTIONAL_RESULT_FIELDS: dict[str, type] = {"first_grasp": bool, "meshes": list}
#: Why an episode failed (``episode_failure``): a name, or None for a success.
FAILURE_FIELD = "failure"


def _record_problem(record: dict, keys: set[str]) -> str | None:
    """What is wrong with an episode record this code wrote, for a protocol of episode ``keys``, or None."""
    if set(record) != {"key", "commit", "result", "timing"}:
        return f"keys {sorted(record)} are not key, commit, result, timing"
    result, timing = record["result"], record["timing"]
    required = {*RESULT_FIELDS, FAILURE_FIELD}
    if not isinstance(result, dict) or not required <= set(result) <= required | set(OPTIONAL_RESULT_FIELDS):
        return f"result must hold {[*RESULT_FIELDS, FAILURE_FIELD]}, and may hold {list(OPTIONAL_RESULT_FIELDS)}"
    for name, kind in OPTIONAL_RESULT_FIELDS.items():
        value = result.get(name, kind())
        valid = isinstance(value, kind) and (kind is bool or all(is_count(v) for v in value))
        if not valid:
            return f"result.{name} must be a JSON {'boolean' if kind is bool else 'list of whole numbers'}, got {value!r:.60}"
    failure = result[FAILURE_FIELD]
    if not (failure is None if result["success"] is True else isinstance(failure, str) and 0 < len(failure) <= 64):
        return f"result.{FAILURE_FIELD} must be null for a success and a reason otherwise, got {failure!r:.60}"
    for name, kind in RESULT_FIELDS.items():
        value = result[name]
        if not isinstance(value, kind) or (kind is not bool and isinstance(value, bool)):
            what = {bool: "boolean", dict: "object", int: "whole number"}.get(kind, "number")  # type: ignore[call-overload]
            return f"result.{name} must be a JSON {what}, got {value!r:.60}"
        if kind is not bool and not isinstance(value, dict) and not (np.isfinite(value) and value >= 0):
            return f"result.{name} must be a number >= 0, got {value!r}"
    if not all(isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and v >= 0
               for k, v in result["failures"].items()):  # fmt: skip
        return "result.failures must map reasons to counts"
    numbers = [timing.get(k) for k in ("wall_seconds", "decision_seconds_median")] if isinstance(timing, dict) else []
    if len(numbers) != 2 or len(timing) != 2 or not all(is_number(n) and n >= 0 for n in numbers):
        return "timing must hold wall_seconds and decision_seconds_median, numbers >= 0"
    spec = result["spec"]
    try:
        options = tuple((k, v) for k, v in spec["options"])
        if set(spec) != {"agent", "task", "seed", "options"} or not all(isinstance(k, str) for k, _ in options):
            raise TypeError
        key = EpisodeSpec(spec["agent"], spec["task"], spec["seed"], options).key
    except (KeyError, TypeError, ValueError):
        return f"result.spec {spec!r:.80} is not an episode's spec"
    if record["key"] != key:
        return f"key {record['key']!r:.80} is not the key of its spec ({key})"
    if key not in keys:
        return f"episode {key} is not one of this protocol's (agents, tasks, seeds and options)"
    return None


def _load(path: Path, code: str, keys: set[str]) -> tuple[dict[str, dict], list[str]]:
    """The finished episodes in ``path`` that this code (``commit()``) ran, by key, and the lines of those
    another commit ran (or that predate the commit field): mixing them would report neither.  A last line cut
    short by an interruption is in neither (that episode runs again).  Any other line that is not a record this
    code wrote for this protocol (episode ``keys``), with the fields and types it writes, is a ``ValueError``
    naming the line: an edited record is refused, never reported."""
    done, stale = {}, []
    lines = path.read_text().splitlines() if path.exists() else []
    for number, line in enumerate(lines, 1):
        where = f"{path} line {number}"
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            if number == len(lines):
                continue
            raise ValueError(f"{where} is not JSON; --resume reads only records this program wrote") from None
        if not isinstance(record, dict):
            raise ValueError(f"{where} is not an episode record (a JSON object)")
        if record.get("commit") == code:
            problem = _record_problem(record, keys)
            if problem is not None:
                raise ValueError(f"{where}: {problem}; --resume keeps only records this program wrote for this "
                                 f"protocol (run without --resume to start afresh)")  # fmt: skip
            done[record["key"]] = record
        else:
            stale.append(line)
    return done, stale


def _run_job(spec: EpisodeSpec) -> dict:
    return {"key": spec.key, **run_episode(spec)}


def _ray_records(specs: list[EpisodeSpec], address: str, imports: list[str]):
    """Episodes as Ray tasks, yielded as they finish (results are the same as local ones: episodes are
    determined by their spec alone); each task imports the ``--import`` modules first."""
    import ray

    from panda_grasp_env.agents.evaluation import import_modules as load
    from panda_grasp_env.agents.evaluation import run_episode as run

    ray.init(address=None if address == "local" else address, include_dashboard=False, log_to_driver=False)
    remote = ray.remote(lambda spec: load(imports) or {"key": spec.key, **run(spec)})
    pending = [remote.remote(spec) for spec in specs]
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            yield ray.get(ready[0])
    finally:
        ray.shutdown()


def run_episodes(specs: list[EpisodeSpec], args: argparse.Namespace, log: Path) -> dict[str, dict]:
    from tqdm import tqdm

    code = commit()
    previous = log.with_name(log.name + ".prev")
    done, stale = _load(log, code, {s.key for s in specs}) if args.resume else ({}, [])
    if not args.resume and log.exists() and log.stat().st_size:  # a fresh run keeps the last one's episodes
        os.replace(log, previous)
        print(f"earlier episodes moved to {previous.name} (continue a run with --resume)")
    if stale:  # kept aside, not mixed in
        with previous.open("a") as handle:
            handle.write("".join(line + "\n" for line in stale))
        print(
            f"{len(stale)} episode(s) run by code other than {code} moved to {previous.name}; this run redoes its own"
        )
    if log.exists():  # keep only whole records (an interruption can cut the last line short)
        write_atomically(log, "".join(json.dumps(r, sort_keys=True) + "\n" for r in done.values()))
    todo = [s for s in specs if s.key not in done]
    wins: Counter[bool] = Counter()
    bar = tqdm(total=len(specs), initial=len(specs) - len(todo), desc="episodes", unit="ep")
    try:
        pool = None
        if args.ray is not None:
            records = _ray_records(todo, args.ray, args.imports)
        elif args.workers == 1:
            records = (_run_job(spec) for spec in todo)
        else:
            pool = multiprocessing.get_context("spawn").Pool(args.workers, import_modules, (args.imports,))
            records = pool.imap_unordered(_run_job, todo)
        for record in records:
            record["commit"] = code
            _append(log, record)
            done[record["key"]] = record
            wins[bool(record["result"]["success"])] += 1
            bar.update(1)
            bar.set_postfix_str(f"{wins[True]}/{wins.total()} succeeded")
        if pool is not None:
            pool.close()
            pool.join()
    except KeyboardInterrupt:
        bar.close()
        print(f"\ninterrupted: {len(done)}/{len(specs)} episodes saved in {log}; finish with --resume")
        raise
    bar.close()
    return {s.key: done[s.key] for s in specs}


def applicable(task: str, metrics: dict) -> dict[str, float | None]:
    """The task's grasp success, action efficiency and cycles per simulated hour, None where a figure does not
    apply: no grasp primitives attempted, low-level episodes (they run to the time limit, so actions per ideal
    action say nothing), or a task without build-and-break cycles."""
    grasps = metrics["grasp_success"]
    return {
        "grasp_success": grasps["rate"] if grasps["n"] else None,
        "action_efficiency": None if is_low_level(*BENCHMARKS[task]) else metrics["action_efficiency"],
        "cycles_per_sim_hour": metrics["cycles_per_sim_hour"] if task == "BuildAndBreak" else None,
        "collateral_per_action": None if is_low_level(*BENCHMARKS[task]) else metrics["collateral_per_action"],
    }


def write_outputs(records: dict[str, dict], args: argparse.Namespace) -> dict:
    import csv

    results = [r["result"] for r in records.values()]
    table = aggregate(results)
    protocol = {
        "agents": args.agents,
        "tasks": args.tasks,
        "full": args.full,
        "env_ids": {t: BENCHMARKS[t][0] for t in args.tasks},
        "seeds": {t: chosen_seeds(args, t) for t in args.tasks},
        "task_options": args.task_options,
        "imports": args.imports,
        "skipped": args.skipped,
    }
    payload = {
        "protocol": protocol,
        "provenance": {"commit": commit(), "versions": versions(), "machine": machine()},
        "metrics": table,
        "episodes": sorted(results, key=lambda r: (r["spec"]["agent"], r["spec"]["task"], r["spec"]["seed"])),
    }
    write_atomically(args.out / "results.json", json.dumps(payload, indent=2, sort_keys=True))
    rows = [
        [
            "agent",
            "task",
            "episodes",
            "trial_success",
            "ci_low",
            "ci_high",
            "completion",
            "grasp_success",
            "action_efficiency",
            "cycles_per_sim_hour",
            "collateral_per_action",
            "failures",
            "episode_failures",
        ]
    ]
    for key, m in table.items():
        agent, task = key.split("/")
        s = m["trial_success"]
        rows.append(
            [
                agent,
                task,
                m["episodes"],
                s["rate"],
                *s["ci95"],
                m["completion"]["rate"],
                *applicable(task, m).values(),  # None: an empty cell
                json.dumps(m["failures"]),
                json.dumps(m["episode_failures"]),
            ]
        )
    buffer = io.StringIO()
    csv.writer(buffer).writerows(rows)
    write_atomically(args.out / "results.csv", buffer.getvalue())
    timing: dict[str, dict] = {}
    for record in records.values():
        key = f"{record['result']['spec']['agent']}/{record['result']['spec']['task']}"
        timing.setdefault(key, {"wall_seconds": [], "decision_seconds_median": []})
        timing[key]["wall_seconds"].append(record["timing"]["wall_seconds"])
        timing[key]["decision_seconds_median"].append(record["timing"]["decision_seconds_median"])
    timing = {
        k: {
            "wall_seconds_per_episode": float(np.median(v["wall_seconds"])),
            "ms_per_decision": 1000 * float(np.median(v["decision_seconds_median"])),
        }
        for k, v in timing.items()
    }
    write_atomically(args.out / "timing.json", json.dumps(timing, indent=2, sort_keys=True))
    return {"table": table, "timing": timing, "protocol": protocol}


def failures_text(m: dict) -> str:
    """The failures cell: why episodes failed (``episode_failures``), then the failed actions by reason."""
    why = ", ".join(f"{k} {v}" for k, v in m.get("episode_failures", {}).items())
    actions = ", ".join(f"{k} {v}" for k, v in m["failures"].items())
    return "; ".join(part for part in (why and f"episodes: {why}", actions and f"actions: {actions}") if part) or "-"


def print_table(summary: dict) -> str:
    lines = [
        "| agent | task | N | trial success (95 % CI) | completion | grasp success | action efficiency | cycles / sim h "
        "| collateral / action | ms / decision | failures (why episodes failed; failed actions) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for key, m in summary["table"].items():
        agent, task = key.split("/")
        s, t, shown = m["trial_success"], summary["timing"][key], applicable(task, m)
        grasps = (
            "—"
            if shown["grasp_success"] is None
            else f"{100 * shown['grasp_success']:.0f} % ({m['grasp_success']['n']})"
        )
        efficiency = "—" if shown["action_efficiency"] is None else f"{100 * shown['action_efficiency']:.0f} %"
        cycles = "—" if shown["cycles_per_sim_hour"] is None else f"{shown['cycles_per_sim_hour']:.0f}"
        collateral = "—" if shown["collateral_per_action"] is None else f"{shown['collateral_per_action']:.2f}"
        lines.append(
            f"| {agent} | {task} | {m['episodes']} | {100 * s['rate']:.0f} % ({100 * s['ci95'][0]:.0f}-{100 * s['ci95'][1]:.0f}) "
            f"| {100 * m['completion']['rate']:.0f} % | {grasps} "
            f"| {efficiency} | {cycles} | {collateral} | {t['ms_per_decision']:.1f} "
            f"| {failures_text(m)} |"
        )
    table = "\n".join(lines)
    print(table)
    return table


def videos(specs: list[EpisodeSpec], out: Path) -> list[Path]:
    """One MP4 per (agent, task): its first seed, replayed (episodes are deterministic) with the recorder on."""
    written = []
    for spec in {(s.agent, s.task): s for s in reversed(specs)}.values():
        path = out / "videos" / f"{spec.agent}_{spec.task}.mp4"
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            run_episode(spec, video=path)
        written.append(path)
    return written


def chosen_checkpoints(args: argparse.Namespace) -> list[Any]:
    """The shipped checkpoints among the chosen agents (a phased agent's parts) that play at least one chosen task."""
    from panda_grasp_env.agents.learned import Checkpoint
    from panda_grasp_env.agents.phased import PHASED_AGENTS

    names: list[str] = []
    for agent in args.agents:
        if agent not in AGENTS and any(skip_reason(agent, task) is None for task in args.tasks):
            names += PHASED_AGENTS[agent].phases.values() if agent in PHASED_AGENTS else [agent]
    return [Checkpoint(name) for name in dict.fromkeys(names)]


def learning_curves(args: argparse.Namespace) -> list[str]:
    """Copy each evaluated checkpoint's learning curve next to the report; Markdown lines that show them."""
    import shutil

    lines = []
    for checkpoint in chosen_checkpoints(args):
        agent = checkpoint.name
        target = args.out / f"curve_{agent}.png"
        shutil.copyfile(checkpoint.path / "curve.png", target)
        lines += [
            f"Learning curve of `{agent}` (model card: agents/checkpoints/{agent}/card.md):",
            "",
            f"![{agent}]({target.name})",
            "",
        ]
    return lines


def report(summary: dict, table_md: str, args: argparse.Namespace, video_paths: list[Path]) -> None:
    lines = [
        f"# {'Full' if args.full else 'Quick'} benchmark",
        "",
        "Planned (perception), oracle (true poses), learned (shipped checkpoints) and random agents through the same",
        "`env.step` loop.",
        "Rates carry 95 % Wilson intervals; action efficiency = ideal actions of completed episodes / actions used.",
        "",
        table_md,
        "",
        "The same with a heatmap, per-task charts, failure reasons, decision times and clips: [report.html](report.html).",
        "",
        "![success](success.png)",
        "",
        "![failures](failures.png)",
        "",
        *learning_curves(args),
        "Videos: " + ", ".join(f"[{p.stem}](videos/{p.name})" for p in video_paths)
        if video_paths
        else "Videos: skipped.",
        "",
        "## Protocol",
        "",
        f"- seeds per (agent, task): {json.dumps({t: describe_seeds(chosen_seeds(args, t)) for t in args.tasks})}",
        f"- options on top of each task's (--task-options): {json.dumps(args.task_options) if args.task_options else 'none'}",
        f"- env ids and options: {json.dumps({t: BENCHMARKS[t] for t in args.tasks})}; a learned checkpoint plays its own task in "
        "the env it was trained in, and another in that task's scene, seeing and acting as it was trained",
        f"- commit {commit()}; versions: {', '.join(f'{k} {v}' for k, v in versions().items())}",
        f"- workers: {args.workers}",
        *(f"- skipped {pair}: {reason}" for pair, reason in args.skipped.items()),
    ]
    write_atomically(args.out / "report.md", "\n".join(lines) + "\n")


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
    try:  # one that cannot load (or would need trust: panda_grasp_env.agents.learned.Checkpoint) stops the run before any episode
        for checkpoint in chosen_checkpoints(args):
            checkpoint.load_policy()
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    specs = episode_specs(args)
    if args.skipped:  # the pairs and their reasons are in the report
        print(
            f"skipped {len(args.skipped)} agent/task pairs that do not apply (which and why: {args.out / 'report.html'})"
        )
    if not specs:
        print("nothing to run: no chosen agent applies to a chosen task", file=sys.stderr)
        return 2
    started = time.perf_counter()
    try:
        records = run_episodes(specs, args, args.out / "episodes.jsonl")
    except KeyboardInterrupt:
        return 130
    except ValueError as error:  # a --resume record refused: before any episode ran
        print(f"error: {error}", file=sys.stderr)
        return 2
    summary = write_outputs(records, args)
    table_md = print_table(summary)
    save_pngs(summary["table"], args.out)
    try:  # the videos replay episodes in the env the last episode left open (a one-worker run's)
        video_paths = [] if args.no_video else videos(specs, args.out)
    finally:
        close_kept_env()
    report(summary, table_md, args, video_paths)
    page = write_page(args.out)
    print(f"{len(specs)} episodes in {time.perf_counter() - started:.0f} s; report: {args.out / 'report.md'}, {page}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
