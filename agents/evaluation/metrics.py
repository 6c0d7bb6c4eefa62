"""Benchmark metrics: rates with 95 % Wilson intervals (clustered where attempts come in episodes), and the
metrics of each ``agent/task`` from its episodes' results.
"""

from __future__ import annotations

from collections import Counter
from typing import Any

import numpy as np


def wilson(successes: int, n: int, z: float = 1.96) -> list[float]:
    """95 % Wilson score interval."""
    return wilson_interval(successes / n, n, z) if n else [0.0, 1.0]


def wilson_interval(p: float, n: float, z: float = 1.96) -> list[float]:
    """Wilson score interval of a rate ``p`` observed over ``n`` (possibly effective, fractional) trials."""
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return [round(max(0.0, float(centre - half)), 4), round(min(1.0, float(centre + half)), 4)]


def rate(successes: int, n: int) -> dict[str, Any]:
    return {"rate": round(successes / n, 4) if n else 0.0, "successes": successes, "n": n, "ci95": wilson(successes, n)}


def clustered_rate(successes: list[int], attempts: list[int]) -> dict[str, Any]:
    """A rate over attempts made in groups (grasps within episodes): the attempts of one episode are not
    independent (the same scene, the same policy), so the 95 % interval is Wilson's at the effective number
    of attempts -- n divided by the design effect, the cluster-robust variance of the ratio over the
    binomial one (never below 1: the interval is at least the per-attempt one)."""
    s, a = np.asarray(successes, dtype=float), np.asarray(attempts, dtype=float)
    total, n = int(s.sum()), int(a.sum())
    result = {**rate(total, n), "design_effect": 1.0}
    p, groups = (total / n if n else 0.0), int((a > 0).sum())
    if groups > 1 and 0.0 < p < 1.0:
        clustered = groups / (groups - 1) * float(((s - p * a) ** 2).sum()) / n**2
        design_effect = max(1.0, clustered / (p * (1 - p) / n))
        effective = n / design_effect
        result["ci95"] = wilson_interval(p, effective)
        result["design_effect"] = round(design_effect, 3)
    return result


def describe_rate(r: dict[str, Any]) -> str:
    """``rate`` / ``clustered_rate`` as text: "72.5 % (335/462, 95 % CI 68.3-76.4[, design effect 1.20])"."""
    low, high = r["ci95"]
    clustered = f", design effect {r['design_effect']:.2f}" if r.get("design_effect", 1.0) > 1.0 else ""
    return f"{100 * r['rate']:.1f} % ({r['successes']}/{r['n']}, 95 % CI {100 * low:.1f}-{100 * high:.1f}{clustered})"


def aggregate(results: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Metrics per ``agent/task`` from episode results (deterministic: no wall-clock figures)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in results:
        groups.setdefault(f"{r['spec']['agent']}/{r['spec']['task']}", []).append(r)
    table = {}
    for key in sorted(groups):
        episodes = sorted(groups[key], key=lambda r: r["spec"]["seed"])
        n = len(episodes)
        actions = sum(r["actions"] for r in episodes)
        ideal_done = sum(r["ideal_actions"] for r in episodes if r["completion"])
        sim_hours = sum(r["sim_seconds"] for r in episodes) / 3600
        failures: Counter[str] = Counter()
        for r in episodes:
            failures.update(r["failures"])
        # An episode recorded before episodes named their failure counts as "unrecorded".
        why = Counter(r.get("failure", "unrecorded") for r in episodes if not r["success"])
        table[key] = {
            "episodes": n,
            "seeds": [r["spec"]["seed"] for r in episodes],
            "trial_success": rate(sum(r["success"] for r in episodes), n),
            "completion": rate(sum(r["completion"] for r in episodes), n),
            "grasp_success": clustered_rate(
                [r["grasps_succeeded"] for r in episodes], [r["grasps_attempted"] for r in episodes]
            ),
            "action_efficiency": round(ideal_done / actions, 4) if actions else 0.0,
            "cycles_per_sim_hour": round(sum(r["cycles"] for r in episodes) / sim_hours, 2) if sim_hours else 0.0,
            "failures": dict(sorted(failures.items())),
            "episode_failures": dict(sorted(why.items())),
            "sim_seconds_per_episode": round(sim_hours * 3600 / n, 3),
            "physics_errors": sum(r["physics_error"] for r in episodes),
            # Objects moved or tipped besides each primitive's targets, per action (see panda_grasp_env.sim.collateral).
            "collateral_per_action": round(sum(r.get("disturbed", 0) for r in episodes) / actions, 4)
            if actions
            else 0.0,
            "transit_contacts": sum(r.get("transit_contacts", 0) for r in episodes),
        }
        if any("first_grasp" in r for r in episodes):  # grasping tasks: episodes whose first grasp attempt held
            table[key]["first_grasp_success"] = rate(sum(r.get("first_grasp", False) for r in episodes), n)
    return table
