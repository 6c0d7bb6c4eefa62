"""Running a protocol's episodes: in this process, in worker processes or as Ray tasks.  Each finished episode
is appended to a log at once, so that an interrupted run resumes without redoing any (``resume``), and a
resumed run keeps only records this code wrote for this protocol.
"""

from __future__ import annotations

import json
import multiprocessing
import os
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from panda_grasp_env.agents.evaluation.episodes import clip_path, first_of_each_pair, run_episode
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec, code_label, import_modules
from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.tooling.reading import MAX_LOG_BYTES, parse_json, read_text
from panda_grasp_env.tooling.runs import ray_tasks, write_atomically


def _append(path: Path, record: dict) -> None:
    """One finished episode per line, flushed to disk at once (an interrupted run keeps it)."""
    with path.open("a") as handle:
        handle.write(json.dumps(record, sort_keys=True) + "\n")
        handle.flush()
        os.fsync(handle.fileno())


#: An episode record's ``result`` fields and their JSON types (``run_episode`` writes them; ``--resume`` checks).
RESULT_FIELDS: dict[str, type | tuple[type, ...]] = {
    "spec": dict,
    "success": bool,
    "completion": bool,
    "actions": int,
    "ideal_actions": int,
    "grasps_attempted": int,
    "grasps_succeeded": int,
    "cycles": int,
    "sim_seconds": (int, float),
    "failures": dict,
    "physics_error": bool,
    "disturbed": int,
    "transit_contacts": int,
}
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
    if not all(
        isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and v >= 0
        for k, v in result["failures"].items()
    ):
        return "result.failures must map reasons to counts"
    numbers = [timing.get(k) for k in ("wall_seconds", "decision_seconds_median")] if isinstance(timing, dict) else []
    if len(numbers) != 2 or len(timing) != 2 or not all(is_number(n) and n >= 0 for n in numbers):
        return "timing must hold wall_seconds and decision_seconds_median, numbers >= 0"
    spec = result["spec"]
    try:
        options = tuple((k, v) for k, v in spec["options"])
        if set(spec) != {"agent", "task", "seed", "options"} or not all(isinstance(k, str) for k, _ in options):
            raise TypeError
        if not (isinstance(spec["agent"], str) and isinstance(spec["task"], str) and is_count(spec["seed"])):
            raise TypeError  # a seed "0" would make the key of seed 0, and sort against the others' ints
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
    text = read_text(path, MAX_LOG_BYTES) if path.exists() or path.is_symlink() else ""
    lines = text.splitlines()
    for number, line in enumerate(lines, 1):
        where = f"{path} line {number}"
        try:
            record = parse_json(line, where)
        except ValueError as error:
            if number == len(lines) and not text.endswith("\n"):  # every record ends its line
                continue
            raise ValueError(f"{error}; --resume reads only records this program wrote") from None
        if not isinstance(record, dict):
            raise ValueError(f"{where} is not an episode record (a JSON object)")
        if record.get("commit") == code:
            problem = _record_problem(record, keys)
            if problem is not None:
                raise ValueError(
                    f"{where}: {problem}; --resume keeps only records this program wrote for this "
                    f"protocol (run without --resume to start afresh)"
                )
            done[record["key"]] = record
        else:
            stale.append(line)
    return done, stale


def _run_job(job: tuple[EpisodeSpec, Path | None]) -> dict:
    spec, video = job
    return {"key": spec.key, **run_episode(spec, video)}


def _imported_job(spec: EpisodeSpec, imports: list[str]) -> dict:
    """A Ray task's episode: it imports the ``imports`` modules first (a fresh worker has not)."""
    import_modules(imports)
    return _run_job((spec, None))


def run_episodes(
    specs: list[EpisodeSpec],
    log: Path,
    *,
    resume: bool = False,
    workers: int = 1,
    ray_address: str | None = None,
    imports: Iterable[str] = (),
    videos: Path | None = None,
) -> dict[str, dict]:
    """Run ``specs`` and return their records by key, in the order of ``specs``: in this process, in ``workers``
    spawned processes, or as Ray tasks on the cluster at ``ray_address`` (``"local"``: one started here);
    worker processes and Ray tasks import the ``imports`` modules first.  Each finished episode is appended to
    ``log`` (JSON lines).  With ``resume`` the episodes ``log`` holds from this code are kept and the rest run
    (``ValueError`` naming a record this code did not write for these specs); without it, an earlier log is
    moved aside to ``<log>.prev``.  With ``videos`` (a results folder), the first episode of each (agent,
    task) is filmed as it is played, to ``episodes.clip_path`` (not on Ray: ``report.videos`` replays those)."""
    from tqdm import tqdm

    code = code_label(imports)
    previous = log.with_name(log.name + ".prev")
    done, stale = _load(log, code, {s.key for s in specs}) if resume else ({}, [])
    if not resume and log.exists() and log.stat().st_size:  # a fresh run keeps the last one's episodes
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
    filmed = {} if videos is None else {s.key: clip_path(videos, s) for s in first_of_each_pair(specs)}
    for path in filmed.values():
        path.parent.mkdir(parents=True, exist_ok=True)
    jobs = [(spec, filmed.get(spec.key)) for spec in todo]
    wins: Counter[bool] = Counter()
    bar = tqdm(total=len(specs), initial=len(specs) - len(todo), desc="episodes", unit="ep")
    try:
        pool = None
        if ray_address is not None:
            records = ray_tasks(_imported_job, [(s, list(imports)) for s in todo], ray_address)
        elif workers == 1:
            records = (_run_job(job) for job in jobs)
        else:
            pool = multiprocessing.get_context("spawn").Pool(workers, import_modules, (list(imports),))
            records = pool.imap_unordered(_run_job, jobs)
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
