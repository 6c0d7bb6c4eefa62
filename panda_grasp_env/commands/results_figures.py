"""The charts of ``evaluate.py``'s results: success.png and failures.png, and the per-task bar charts that
report.html inlines as SVG (``results_page``).

matplotlib's: one small horizontal-bar chart per task (every bar labelled by its agent and readable however
many agents ran), bars coloured by agent family (``FAMILY_COLOURS``, the Okabe–Ito palette, told apart in
colour-blind vision too), the legend in a strip of its own above the charts.
"""

from __future__ import annotations

import io
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation.protocol import AGENTS
from panda_grasp_env.agents.policies.registry import NAMED_AGENTS

#: Agent family -> bar colour (Okabe–Ito).  The built-in agents' families; agents registered by name are
#: ``registered``, every other agent is a learned checkpoint.
FAMILY_COLOURS = {
    "scripted": "#0072B2",
    "expert": "#009E73",
    "learned": "#E69F00",
    "registered": "#CC79A7",
    "random": "#999999",
}
FAMILY_OF = {"planned": "scripted", "oracle": "scripted", "expert": "expert", "random": "random"}
assert set(FAMILY_OF) == set(AGENTS)


def family(agent: str) -> str:
    """``scripted`` (planned baselines and their oracles), ``expert``, ``random``, ``registered`` (an agent
    registered by name: ``registry.register_agent``) or ``learned`` (a checkpoint)."""
    return FAMILY_OF.get(agent) or ("registered" if agent in NAMED_AGENTS else "learned")


def agent_order(agents: Iterable[str]) -> list[str]:
    """Agents grouped by family (scripted, expert, learned, random), by name within one."""
    rank = {name: i for i, name in enumerate(FAMILY_COLOURS)}
    return sorted(set(agents), key=lambda a: (rank[family(a)], a))


def split_key(key: str) -> tuple[str, str]:
    agent, task = key.split("/")
    return agent, task


# --- charts ----------------------------------------------------------------------------------------------------


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _family_legend(figure: Any, families: Iterable[str]) -> None:
    """The families present, in a strip of their own at the top of ``figure`` (it covers no axes)."""
    from matplotlib.patches import Patch

    present = set(families)
    shown = [f for f in FAMILY_COLOURS if f in present]
    figure.legend(
        [Patch(color=FAMILY_COLOURS[f]) for f in shown], shown, loc="upper center", ncol=len(shown), frameon=False
    )


def success_figure(table: dict[str, dict]) -> Any:
    """Trial success with 95 % intervals: one panel per task, one labelled horizontal bar per agent."""
    plt = _pyplot()
    tasks = list(dict.fromkeys(split_key(k)[1] for k in table))
    by_task = {t: agent_order(split_key(k)[0] for k in table if split_key(k)[1] == t) for t in tasks}
    columns = min(3, len(tasks))
    grid_rows = -(-len(tasks) // columns)
    rows_per = [max(len(by_task[t]) for t in tasks[i * columns : (i + 1) * columns]) for i in range(grid_rows)]
    height = sum(0.28 * r + 0.9 for r in rows_per) + 0.6
    figure, axes = plt.subplots(
        grid_rows,
        columns,
        figsize=(4.4 * columns, height),
        squeeze=False,
        gridspec_kw={"height_ratios": [r + 2 for r in rows_per]},
    )
    for axis, task in zip(axes.flat, tasks):
        agents = by_task[task]
        rates = np.array([table[f"{a}/{task}"]["trial_success"]["rate"] for a in agents])
        ci = np.array([table[f"{a}/{task}"]["trial_success"]["ci95"] for a in agents])
        y = np.arange(len(agents))
        axis.barh(
            y,
            rates,
            color=[FAMILY_COLOURS[family(a)] for a in agents],
            height=0.7,
            xerr=[rates - ci[:, 0], ci[:, 1] - rates],
            error_kw={"ecolor": "#333", "capsize": 2, "lw": 0.8},
        )
        for yi, a in zip(y, agents):
            n = table[f"{a}/{task}"]["trial_success"]["n"]
            axis.text(
                1.02,
                yi,
                f"{100 * table[f'{a}/{task}']['trial_success']['rate']:.0f} % (n {n})",
                va="center",
                fontsize=7,
                transform=axis.get_yaxis_transform(),
            )
        axis.set_yticks(y, agents, fontsize=8)
        axis.invert_yaxis()
        axis.set_xlim(0, 1)
        axis.set_title(task, fontsize=10, loc="left")
        axis.grid(axis="x", alpha=0.3)
        axis.tick_params(axis="x", labelsize=7)
    for axis in axes.flat[len(tasks) :]:
        axis.set_visible(False)
    figure.supxlabel("trial success (bars: 95 % Wilson interval)", fontsize=9)
    figure.tight_layout(rect=(0, 0, 1, 1 - 0.45 / height), w_pad=6)
    _family_legend(figure, (family(split_key(k)[0]) for k in table))
    return figure


def failures_figure(table: dict[str, dict]) -> Any:
    """Why episodes failed, and which actions failed, per (agent, task) that had any: stacked horizontal bars,
    one labelled row each, the reasons' legend under each panel."""
    from matplotlib.ticker import MaxNLocator

    plt = _pyplot()
    panels = [("episode_failures", "failed episodes, by why"), ("failures", "failed actions, by reason")]
    shown = [[k for k in pair_order(table) if table[k].get(field)] for field, _ in panels]
    rows = max(1, *map(len, shown))
    figure, axes = plt.subplots(1, 2, figsize=(13, 0.26 * rows + 2.6))
    for axis, (field, title), keys in zip(axes, panels, shown):
        axis.set_title(title, fontsize=10, loc="left")
        if not keys:
            axis.text(0.5, 0.5, "none", ha="center", va="center", transform=axis.transAxes)
            axis.set_axis_off()
            continue
        reasons = sorted({r for k in keys for r in table[k][field]})
        colours = plt.get_cmap("tab20")(np.linspace(0, 1, 20))[: len(reasons)] if len(reasons) <= 20 else None
        left = np.zeros(len(keys))
        for i, reason in enumerate(reasons):
            counts = np.array([table[k][field].get(reason, 0) for k in keys], dtype=float)
            axis.barh(
                range(len(keys)),
                counts,
                left=left,
                label=reason,
                height=0.7,
                color=None if colours is None else colours[i],
            )
            left += counts
        axis.set_yticks(range(len(keys)), [k.replace("/", " / ") for k in keys], fontsize=7)
        axis.set_ylim(len(keys) - 0.5, -0.5)
        axis.xaxis.set_major_locator(MaxNLocator(integer=True))  # counts
        axis.grid(axis="x", alpha=0.3)
        axis.tick_params(axis="x", labelsize=7)
        axis.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.06), ncol=3, frameon=False)
    figure.tight_layout()
    return figure


def pair_order(table: dict[str, dict]) -> list[str]:
    rank = {a: i for i, a in enumerate(agent_order(split_key(k)[0] for k in table))}
    return sorted(table, key=lambda k: (rank[split_key(k)[0]], split_key(k)[1]))


def save_pngs(table: dict[str, dict], out: Path) -> None:
    """success.png and failures.png in ``out``."""
    plt = _pyplot()
    for name, make in (("success.png", success_figure), ("failures.png", failures_figure)):
        figure = make(table)
        figure.savefig(out / name, dpi=110)
        plt.close(figure)


def svg(figure: Any) -> str:
    """``figure`` as inline SVG (text kept as text), closed afterwards."""
    plt = _pyplot()
    buffer = io.StringIO()
    with plt.rc_context({"svg.fonttype": "none", "svg.hashsalt": "panda_grasp_env"}):
        figure.savefig(buffer, format="svg")
    plt.close(figure)
    text = buffer.getvalue()
    return text[text.index("<svg") :]
