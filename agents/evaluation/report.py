"""What a benchmark run leaves in its folder: results.json and results.csv (deterministic: the same protocol
gives identical files), timing.json, report.md, the learning curves of the checkpoints that played, and one
MP4 per (agent, task).  ``panda_grasp_env.commands.results_page`` draws report.html and the charts from them.
"""

from __future__ import annotations

import csv
import io
import json
import shutil
from pathlib import Path

import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.evaluation.episodes import clip_path, first_of_each_pair, run_episode
from panda_grasp_env.agents.evaluation.metrics import aggregate
from panda_grasp_env.agents.evaluation.protocol import (
    EpisodeSpec,
    RunProtocol,
    code_label,
    imported_files,
    is_low_level,
)
from panda_grasp_env.tooling.runs import machine, versions, write_atomically


def describe_seeds(seeds: list[int]) -> str:
    """``"a..b (n)"`` for a run of consecutive seeds, else the list."""
    if seeds == list(range(seeds[0], seeds[0] + len(seeds))):
        return f"{seeds[0]}..{seeds[-1]} ({len(seeds)})"
    return ",".join(map(str, seeds))


def applicable(task: str, metrics: dict) -> dict[str, float | None]:
    """The task's grasp success, action efficiency and cycles per simulated hour, None where a figure does not
    apply: no grasp primitives attempted, low-level episodes (they run to the time limit, so actions per ideal
    action say nothing), or a task without build-and-break cycles."""
    grasps = metrics["grasp_success"]
    low_level = is_low_level(BENCHMARKS[task].env_id, BENCHMARKS[task].options)
    return {
        "grasp_success": grasps["rate"] if grasps["n"] else None,
        "action_efficiency": None if low_level else metrics["action_efficiency"],
        "cycles_per_sim_hour": metrics["cycles_per_sim_hour"] if task == "BuildAndBreak" else None,
        "collateral_per_action": None if low_level else metrics["collateral_per_action"],
    }


def write_results(records: dict[str, dict], protocol: RunProtocol, skipped: dict[str, str], out: Path) -> dict:
    """results.json (protocol, provenance, metrics, episodes), results.csv (the metrics) and timing.json (wall
    time per episode, milliseconds per decision) in ``out`` from the episode ``records``; returns the metrics
    ``table``, the ``timing`` and the ``protocol`` record."""
    results = [r["result"] for r in records.values()]
    table = aggregate(results)
    protocol_record = protocol.record(skipped)
    payload = {
        "protocol": protocol_record,
        "provenance": {"commit": code_label(protocol.imports), "versions": versions(), "machine": machine()},
        "metrics": table,
        "episodes": sorted(results, key=lambda r: (r["spec"]["agent"], r["spec"]["task"], r["spec"]["seed"])),
    }
    write_atomically(out / "results.json", json.dumps(payload, indent=2, sort_keys=True))
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
    write_atomically(out / "results.csv", buffer.getvalue())
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
    write_atomically(out / "timing.json", json.dumps(timing, indent=2, sort_keys=True))
    return {"table": table, "timing": timing, "protocol": protocol_record}


def failures_text(m: dict) -> str:
    """The failures cell: why episodes failed (``episode_failures``), then the failed actions by reason."""
    why = ", ".join(f"{k} {v}" for k, v in m.get("episode_failures", {}).items())
    actions = ", ".join(f"{k} {v}" for k, v in m["failures"].items())
    return "; ".join(part for part in (why and f"episodes: {why}", actions and f"actions: {actions}") if part) or "-"


def results_table(summary: dict) -> str:
    """The metrics of ``write_results``' ``summary`` as a Markdown table, one row per (agent, task)."""
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
    return "\n".join(lines)


def videos(specs: list[EpisodeSpec], out: Path) -> list[Path]:
    """One MP4 per (agent, task), of its first seed: ``run_episodes`` films it while playing it, and this
    replays (episodes are deterministic) only an episode whose clip is missing, as after a ``--resume`` of a run
    made without videos."""
    written = []
    for spec in first_of_each_pair(specs):
        path = clip_path(out, spec)
        if not path.exists():
            path.parent.mkdir(parents=True, exist_ok=True)
            run_episode(spec, video=path)
        written.append(path)
    return written


def learning_curves(protocol: RunProtocol, out: Path) -> list[str]:
    """Copy each evaluated checkpoint's learning curve into ``out``; Markdown lines that show them."""
    lines = []
    for checkpoint in protocol.checkpoints():
        agent = checkpoint.name
        target = out / f"curve_{agent}.png"
        shutil.copyfile(checkpoint.path / "curve.png", target)
        lines += [
            f"Learning curve of `{agent}` (model card: agents/checkpoints/{agent}/card.md):",
            "",
            f"![{agent}]({target.name})",
            "",
        ]
    return lines


def write_report(
    out: Path,
    protocol: RunProtocol,
    skipped: dict[str, str],
    table_md: str,
    video_paths: list[Path],
    workers: int,
) -> None:
    """report.md in ``out``: the results table (``results_table``), the charts, learning curves and videos, and
    the protocol (seeds, options, env ids, commit and versions, ``workers``, the ``skipped`` pairs)."""
    lines = [
        f"# {'Full' if protocol.full else 'Quick'} benchmark",
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
        *learning_curves(protocol, out),
        "Videos: " + ", ".join(f"[{p.stem}](videos/{p.name})" for p in video_paths)
        if video_paths
        else "Videos: skipped.",
        "",
        "## Protocol",
        "",
        f"- seeds per (agent, task): {json.dumps({t: describe_seeds(protocol.seeds_of(t)) for t in protocol.tasks})}",
        f"- options on top of each task's (--task-options): {json.dumps(dict(protocol.task_options)) if protocol.task_options else 'none'}",
        f"- env ids and options: {json.dumps({t: [BENCHMARKS[t].env_id, BENCHMARKS[t].options] for t in protocol.tasks})}; a learned checkpoint plays its own task in "
        "the env it was trained in, and another in that task's scene, seeing and acting as it was trained",
        f"- commit {code_label(protocol.imports)}; versions: {', '.join(f'{k} {v}' for k, v in versions().items())}",
        *(f"- imported {f['module']}: {f['file']}, SHA-256 {f['sha256']}" for f in imported_files(protocol.imports)),
        f"- workers: {workers}",
        *(f"- skipped {pair}: {reason}" for pair, reason in skipped.items()),
    ]
    write_atomically(out / "report.md", "\n".join(lines) + "\n")
