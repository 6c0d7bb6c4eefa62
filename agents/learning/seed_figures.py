"""A config's figures over training seeds (``train.py --seeds``; ``seed_runs``): the runs' held-out test
figures aggregated with ``rliable`` (Agarwal et al. 2021) -- interquartile mean, mean and optimality
gap with 95 % stratified-bootstrap intervals, and the performance profile (the fraction of runs scoring above
each threshold tau, with its bootstrap band) -- and their tables and plot for study.md, the model card and
evaluate.py's report.html."""

from __future__ import annotations

import dataclasses
import html
import io
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation.metrics import describe_rate
from panda_grasp_env.agents.evaluation.protocol import is_low_level
from panda_grasp_env.agents.learning.config import TrainConfig
from panda_grasp_env.tooling.runs import commit, versions

#: Bootstrap resamples of the aggregates' intervals and of the profile's band (rliable's default for profiles;
#: its IQM costs ~1 ms a resample, so 50,000 took a minute per metric), and the seed they are drawn from.
BOOTSTRAP_REPS = 2_000
BOOTSTRAP_SEED = 0
#: The aggregates, in rliable's names and in the table's words.  (rliable's median is the median over tasks of
#: the per-task mean: for one task, the mean again.)
AGGREGATES = {"iqm": "IQM", "mean": "mean", "optimality_gap": "optimality gap"}


def study_metrics(config: TrainConfig) -> list[str]:
    """The figures aggregated: trial success, and action efficiency where actions are primitives."""
    return ["trial_success"] + ([] if is_low_level(config.env_id, config.env_kwargs) else ["action_efficiency"])


def score(final: dict[str, Any], metric: str) -> float:
    return rate_of(final["metrics"][metric])


def rate_of(value: dict[str, Any] | float) -> float:
    """A figure's rate: a rate's ``rate``, or the number itself."""
    return float(value["rate"] if isinstance(value, dict) else value)


def aggregate_runs(scores: np.ndarray) -> dict[str, Any]:
    """rliable's aggregates of ``scores`` (runs x tasks, in [0, 1]) with 95 % stratified-bootstrap intervals,
    and the performance profile over thresholds 0, 0.01, ..., 1."""
    from rliable import library as rly
    from rliable import metrics

    functions = {name: getattr(metrics, f"aggregate_{name}") for name in AGGREGATES}

    def every(x: np.ndarray) -> np.ndarray:
        return np.array([f(x) for f in functions.values()])

    def estimates(function: Any) -> tuple[np.ndarray, np.ndarray]:
        # rliable's StratifiedBootstrap draws its resamples from numpy's global generator (its update_indices
        # calls np.random.choice and ignores the random_state it hands arch), so the bootstrap is seeded by
        # seeding that generator, and the caller's global state is put back afterwards.
        saved = np.random.get_state()
        np.random.seed(BOOTSTRAP_SEED)
        try:
            points, intervals = rly.get_interval_estimates({"runs": scores}, function, reps=BOOTSTRAP_REPS)
        finally:
            np.random.set_state(saved)
        return points["runs"], intervals["runs"]

    points, intervals = estimates(every)
    taus = np.linspace(0.0, 1.0, 101)
    # The performance profile (rliable's create_performance_profile, whose bootstrap takes no seed): the
    # fraction of runs whose score exceeds each tau.
    profile, bands = estimates(lambda x: rly.score_distributions(x, taus))
    return {
        "aggregates": {
            name: [round(float(points[i]), 4), round(float(intervals[0, i]), 4), round(float(intervals[1, i]), 4)]
            for i, name in enumerate(functions)
        },
        "profile": {
            "tau": taus.round(2).tolist(),
            "fraction": np.round(profile, 4).tolist(),
            "low": np.round(bands[0], 4).tolist(),
            "high": np.round(bands[1], 4).tolist(),
        },
    }


def tier_metrics(outcomes: list[dict[str, Any]]) -> dict[str, str]:
    """``trial_success_tier_<t>`` for each tier every run's test played (structure tasks), and the tier."""
    tiers = [set(o["final"]["metrics"].get("trial_success_by_tier", {})) for o in outcomes]
    return {f"trial_success_tier_{t}": t for t in sorted(set.intersection(*tiers), key=int)} if tiers else {}


def study_summary(config: TrainConfig, outcomes: list[dict[str, Any]]) -> dict[str, Any]:
    """study.json's content: the config (seed aside), each run's held-out figures, and per metric rliable's
    aggregates and performance profile over the runs; on structure tasks also trial success per tier."""
    shared = {k: v for k, v in dataclasses.asdict(config).items() if k != "seed"}
    by_tier = tier_metrics(outcomes)

    def figures(final: dict[str, Any]) -> dict[str, Any]:
        metrics = final["metrics"]
        tiers = {name: metrics["trial_success_by_tier"][tier] for name, tier in by_tier.items()}
        return {**{m: metrics[m] for m in study_metrics(config)}, **tiers}

    runs = [
        {
            "seed": o["seed"],
            "run_dir": o["run_dir"],
            "steps": o["final"]["steps"],
            "wall_seconds": o["final"]["wall_seconds"],
            "test_seeds": o["final"]["test_seeds"],
            "test_commit": o["final"].get("test_commit"),
            **figures(o["final"]),
        }
        for o in outcomes
    ]
    by_metric = {
        m: aggregate_runs(np.array([[rate_of(run[m])] for run in runs])) for m in [*study_metrics(config), *by_tier]
    }
    return {
        "name": config.name,
        "env_id": config.env_id,
        "algo": config.algo,
        "seeds": [o["seed"] for o in outcomes],
        "config": shared,
        "runs": runs,
        "metrics": by_metric,
        "bootstrap": {
            "method": "rliable stratified bootstrap, percentile intervals",
            "confidence": 0.95,
            "reps": BOOTSTRAP_REPS,
            "seed": BOOTSTRAP_SEED,
        },
        "commit": commit(),
        "versions": versions(("rliable", "stable-baselines3", "torch", "mujoco")),
    }


def _interval(triple: list[float]) -> str:
    point, low, high = triple
    return f"{100 * point:.1f} % ({100 * low:.1f}–{100 * high:.1f})"


def study_rows(study: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    """The aggregate table: one row per metric, one column per aggregate (95 % stratified-bootstrap CI)."""
    header = ["metric", *(f"{label} (95 % CI)" for label in AGGREGATES.values()), "runs"]
    rows = [
        [metric.replace("_", " "), *(_interval(figures["aggregates"][a]) for a in AGGREGATES), str(len(study["runs"]))]
        for metric, figures in study["metrics"].items()
    ]
    return header, rows


def run_rows(study: dict[str, Any]) -> tuple[list[str], list[list[str]]]:
    metrics = list(study["metrics"])
    header = ["seed", "steps", "wall time", *(m.replace("_", " ") for m in metrics)]
    rows = []
    for run in study["runs"]:
        figures = [describe_rate(run[m]) if isinstance(run[m], dict) else f"{100 * run[m]:.1f} %" for m in metrics]
        rows.append([str(run["seed"]), str(run["steps"]), f"{run['wall_seconds'] / 60:.1f} min", *figures])
    return header, rows


def study_markdown(study: dict[str, Any]) -> str:
    """The study as Markdown: what it is, the aggregate table and the per-run table."""

    def table(header: list[str], rows: list[list[str]]) -> list[str]:
        return [
            "| " + " | ".join(header) + " |",
            "|" + "---|" * len(header),
            *("| " + " | ".join(r) + " |" for r in rows),
        ]

    test = study["runs"][0]["test_seeds"]
    lines = [
        f"`{study['algo']}` on `{study['env_id']}`, the same config trained on seeds "
        f"{', '.join(map(str, study['seeds']))}; each run's best validated policy tested on held-out seeds "
        f"{test[0]}-{test[1]}. Aggregated over runs with `rliable` (IQM: interquartile mean; 95 % stratified-"
        f"bootstrap intervals, {study['bootstrap']['reps']} resamples; commit {study['commit']}):",
        "",
        *table(*study_rows(study)),
        "",
        *table(*run_rows(study)),
    ]
    return "\n".join(lines)


def profile_figure(study: dict[str, Any]) -> Any:
    """The performance profiles: fraction of runs scoring above tau, with the 95 % bootstrap band."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axis = plt.subplots(figsize=(6, 3.4))
    for metric, figures in study["metrics"].items():
        p = figures["profile"]
        axis.plot(p["tau"], p["fraction"], label=metric.replace("_", " "))
        axis.fill_between(p["tau"], p["low"], p["high"], alpha=0.2)
    axis.set_xlabel("threshold tau (score of a run)")
    axis.set_ylabel("fraction of runs > tau")
    axis.set_ylim(-0.02, 1.02)
    axis.grid(alpha=0.3)
    axis.set_title(f"{study['name']}: performance profile over {len(study['runs'])} training seeds", fontsize=10)
    figure.tight_layout(rect=(0, 0.1, 1, 1))
    figure.legend(loc="lower center", ncol=len(study["metrics"]), frameon=False)
    return figure


def study_html(study: dict[str, Any]) -> str:
    """The study for report.html: both tables and the profile as inline SVG."""
    import matplotlib.pyplot as plt

    def table(header: list[str], rows: list[list[str]]) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
        return f"<table class='plain'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    buffer = io.StringIO()
    figure = profile_figure(study)
    with plt.rc_context({"svg.fonttype": "none", "svg.hashsalt": "panda_grasp_env"}):
        figure.savefig(buffer, format="svg")
    plt.close(figure)
    picture = buffer.getvalue()
    return (
        f"<h4>Over {len(study['runs'])} training seeds ({html.escape(', '.join(map(str, study['seeds'])))})</h4>"
        + table(*study_rows(study))
        + table(*run_rows(study))
        + picture[picture.index("<svg") :]
    )
