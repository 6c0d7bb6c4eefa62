"""Did my change matter?  ``evaluate.py compare RUN_A RUN_B`` (or ``panda-evaluate compare``) compares two
results folders (``evaluate.py --out``) cell by cell: for each (agent, task) both ran, the difference in each
rate, tested, and a verdict — "better", "worse" or "no detectable change" (B against A) — at a stated level
after a correction for the number of tests.  ``--agents A,B`` compares two agents instead, task by task:
A's cells in RUN_A against B's in RUN_B (one run may be both).

- Trial success and completion (one outcome per episode): Fisher's exact test for two proportions
  (two-sided; conditional, so conservative at small N).
- Grasp success (grasps cluster within episodes) and action efficiency (a ratio of sums over episodes): a
  two-sided permutation test that shuffles whole episodes between the runs (``PERMUTATIONS`` draws from a
  fixed seed), so the clustering is respected and the result repeats.
- The p-values of all tests are corrected together, Holm's step-down method by default (family-wise error
  at ``--alpha``) or Benjamini–Hochberg (``--correction bh``, false discovery rate).

Runs of different protocols are not compared: other seeds for a task, other task options or other env ids
make the command refuse (exit 2).  Other package versions, machine or (of course) commit are named in a loud
warning: the comparison is what the versions changed too.  Output: the terminal, and compare.html (``--out``,
default beside RUN_B's report).
"""

from __future__ import annotations

import argparse
import html
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.evaluation.protocol import is_low_level
from panda_grasp_env.agents.evaluation.report import describe_seeds
from panda_grasp_env.commands.results_figures import agent_order, split_key
from panda_grasp_env.commands.results_page import page_html, table_html
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json
from panda_grasp_env.tooling.runs import write_atomically

#: Shuffles of the permutation tests, and the seed they are drawn from.
PERMUTATIONS = 9999
PERMUTATION_SEED = 0
CORRECTIONS = {"holm": "Holm", "bh": "Benjamini–Hochberg"}


@dataclass(frozen=True)
class Test:
    """One metric of one (agent, task) in both runs: the figures, the raw and the corrected p-value, the verdict."""

    agent: str
    task: str
    metric: str
    a: float
    b: float
    n_a: int
    n_b: int
    test: str
    p: float
    p_adjusted: float = 1.0
    verdict: str = "no detectable change"

    @property
    def difference(self) -> float:
        return self.b - self.a


def load(folder: Path) -> dict[str, Any]:
    """A run's results.json; ``ValueError`` naming the folder if it has none."""
    path = Path(folder) / "results.json"
    try:
        return read_json(path, MAX_DOCUMENT_BYTES)
    except ValueError as error:  # the reader names the file: missing, not a regular file, too large, not JSON
        raise ValueError(f"{folder} is not a finished evaluate.py results folder ({error})") from None


def one_agent(results: dict[str, Any], agent: str, label: str) -> dict[str, Any]:
    """``results`` with only ``agent``'s cells and episodes, the agent named ``label``: two agents' cells
    compared as one (``--agents``).  ``ValueError`` if the run has no episode of ``agent``."""
    metrics = {
        f"{label}/{task}": figures
        for key, figures in results["metrics"].items()
        for name, task in [split_key(key)]
        if name == agent
    }
    if not metrics:
        raise ValueError(f"the run has no episodes of agent {agent!r}")
    episodes = [
        {**e, "spec": {**e["spec"], "agent": label}} for e in results["episodes"] if e["spec"]["agent"] == agent
    ]
    return {**results, "metrics": metrics, "episodes": episodes}


def protocol_differences(a: dict[str, Any], b: dict[str, Any]) -> tuple[list[str], list[str]]:
    """(reasons to refuse, warnings): seeds of a task both ran, task options and env ids must agree; versions
    and machine should."""
    pa, pb = a["protocol"], b["protocol"]
    refuse = []
    for task in sorted(set(pa["tasks"]) & set(pb["tasks"])):
        if pa["seeds"][task] != pb["seeds"][task]:
            refuse.append(
                f"{task} ran on other seeds: {describe_seeds(pa['seeds'][task])} in A, {describe_seeds(pb['seeds'][task])} in B"
            )
        if pa.get("env_ids", {}).get(task) != pb.get("env_ids", {}).get(task):
            refuse.append(
                f"{task} ran in other envs: {pa.get('env_ids', {}).get(task)} / {pb.get('env_ids', {}).get(task)}"
            )
    if pa.get("task_options", {}) != pb.get("task_options", {}):
        refuse.append(
            f"other task options: {json.dumps(pa.get('task_options'))} in A, {json.dumps(pb.get('task_options'))} in B"
        )
    warn = []
    va, vb = a.get("provenance", {}).get("versions", {}), b.get("provenance", {}).get("versions", {})
    changed = [
        f"{k} {va.get(k, 'absent')} -> {vb.get(k, 'absent')}"
        for k in sorted(set(va) | set(vb))
        if va.get(k) != vb.get(k)
    ]
    if changed:
        warn.append("other package versions (the comparison measures them too): " + ", ".join(changed))
    if not va or not vb:
        warn.append("a run records no versions (run before evaluate.py recorded them): they may differ")
    ma, mb = a.get("provenance", {}).get("machine"), b.get("provenance", {}).get("machine")
    if ma != mb:
        warn.append(f"other machines ({ma} / {mb}): only wall-clock figures should depend on it")
    return refuse, warn


def fisher(successes_a: int, n_a: int, successes_b: int, n_b: int) -> float:
    """Two-sided p-value of Fisher's exact test that two proportions are equal."""
    from scipy.stats import fisher_exact

    return float(fisher_exact([[successes_a, n_a - successes_a], [successes_b, n_b - successes_b]]).pvalue)


def ratio_permutation(numerators: np.ndarray, denominators: np.ndarray, in_a: np.ndarray) -> float:
    """Two-sided permutation p-value for the difference of two ratios of sums (sum of numerators over sum of
    denominators, per run), shuffling whole episodes (rows) between the runs; ``in_a`` marks run A's rows."""
    rng = np.random.default_rng(PERMUTATION_SEED)

    def difference(mask: np.ndarray) -> np.ndarray:  # mask: (..., episodes) bool, True for run A
        num_a, den_a = (mask * numerators).sum(-1), (mask * denominators).sum(-1)
        num_b, den_b = numerators.sum() - num_a, denominators.sum() - den_a
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where((den_a > 0) & (den_b > 0), num_b / den_b - num_a / den_a, 0.0)

    observed = abs(float(difference(in_a)))
    shuffled = np.array([rng.permutation(in_a) for _ in range(PERMUTATIONS)])
    extreme = int((np.abs(difference(shuffled)) >= observed - 1e-12).sum())
    return (extreme + 1) / (PERMUTATIONS + 1)


def _episodes(results: dict[str, Any]) -> dict[str, list[dict[str, Any]]]:
    by_pair: dict[str, list[dict[str, Any]]] = {}
    for e in results["episodes"]:
        by_pair.setdefault(f"{e['spec']['agent']}/{e['spec']['task']}", []).append(e)
    return by_pair


def cell_tests(key: str, a: dict[str, Any], b: dict[str, Any], ea: list[dict], eb: list[dict]) -> list[Test]:
    """The tests of one (agent, task): ``a``/``b`` its metrics in each run, ``ea``/``eb`` its episodes."""
    agent, task = split_key(key)
    tests = []
    for metric in ("trial_success", "completion"):
        ra, rb = a[metric], b[metric]
        p = fisher(ra["successes"], ra["n"], rb["successes"], rb["n"])
        tests.append(Test(agent, task, metric, ra["rate"], rb["rate"], ra["n"], rb["n"], "Fisher exact", p))
    in_a = np.array([True] * len(ea) + [False] * len(eb))
    episodes = ea + eb
    if a["grasp_success"]["n"] and b["grasp_success"]["n"]:
        p = ratio_permutation(
            np.array([e["grasps_succeeded"] for e in episodes], float),
            np.array([e["grasps_attempted"] for e in episodes], float),
            in_a,
        )
        tests.append(
            Test(
                agent,
                task,
                "grasp_success",
                a["grasp_success"]["rate"],
                b["grasp_success"]["rate"],
                a["grasp_success"]["n"],
                b["grasp_success"]["n"],
                "episode permutation",
                p,
            )
        )
    benchmark = BENCHMARKS[task]
    if not is_low_level(benchmark.env_id, benchmark.options):
        p = ratio_permutation(
            np.array([e["ideal_actions"] * e["completion"] for e in episodes], float),
            np.array([e["actions"] for e in episodes], float),
            in_a,
        )
        tests.append(
            Test(
                agent,
                task,
                "action_efficiency",
                a["action_efficiency"],
                b["action_efficiency"],
                len(ea),
                len(eb),
                "episode permutation",
                p,
            )
        )
    return tests


def adjust(p_values: list[float], method: str) -> list[float]:
    """p-values corrected for their number: Holm's step-down (``holm``) or Benjamini–Hochberg's (``bh``)."""
    p = np.asarray(p_values, dtype=float)
    if p.size == 0:
        return []
    order = np.argsort(p)
    m = p.size
    if method == "holm":
        stepped = np.maximum.accumulate((m - np.arange(m)) * p[order])
    elif method == "bh":
        stepped = np.minimum.accumulate(((m / np.arange(1, m + 1)) * p[order])[::-1])[::-1]
    else:
        raise ValueError(f"unknown correction {method!r}; valid: {list(CORRECTIONS)}")
    adjusted = np.empty(m)
    adjusted[order] = np.minimum(stepped, 1.0)
    return adjusted.tolist()


def compare(a: dict[str, Any], b: dict[str, Any], alpha: float = 0.05, method: str = "holm") -> list[Test]:
    """Every test of every (agent, task) both runs hold, corrected together, with verdicts for B against A."""
    ea, eb = _episodes(a), _episodes(b)
    tests = []
    for key in sorted(set(a["metrics"]) & set(b["metrics"])):
        tests += cell_tests(key, a["metrics"][key], b["metrics"][key], ea[key], eb[key])
    adjusted = adjust([t.p for t in tests], method)
    verdicts = []
    for t, p in zip(tests, adjusted):
        verdict = (
            "no detectable change" if p >= alpha or t.difference == 0 else "better" if t.difference > 0 else "worse"
        )
        verdicts.append(Test(**{**t.__dict__, "p_adjusted": p, "verdict": verdict}))
    return verdicts


def cell_verdicts(tests: list[Test]) -> dict[str, str]:
    """One verdict per (agent, task): "worse" if any of its metrics is worse, else "better" if any is better."""
    cells: dict[str, str] = {}
    for t in tests:
        key, now = f"{t.agent}/{t.task}", cells.get(f"{t.agent}/{t.task}", "no detectable change")
        cells[key] = "worse" if "worse" in (now, t.verdict) else "better" if "better" in (now, t.verdict) else now
    return cells


def _figure(metric: str, value: float) -> str:
    return f"{100 * value:.0f} %"


def terminal_lines(tests: list[Test], alpha: float, method: str, only_a: list[str], only_b: list[str]) -> list[str]:
    """What the terminal shows: the changed metrics one a line, then one summary line."""
    lines = []
    for t in tests:
        if t.verdict != "no detectable change":
            lines.append(
                f"{t.verdict.upper():6s} {t.agent}/{t.task} {t.metric}: {_figure(t.metric, t.a)} -> "
                f"{_figure(t.metric, t.b)} ({100 * t.difference:+.0f} pp; {t.test}, corrected p "
                f"{t.p_adjusted:.3g}; N {t.n_a} / {t.n_b})"
            )
    cells = cell_verdicts(tests)
    counts = {v: sum(c == v for c in cells.values()) for v in ("better", "worse", "no detectable change")}
    lines.append(
        f"{len(cells)} (agent, task) cells, {len(tests)} tests at level {alpha} ({CORRECTIONS[method]}-"
        f"corrected): {counts['better']} better, {counts['worse']} worse, "
        f"{counts['no detectable change']} no detectable change"
    )
    for name, keys in (("A", only_a), ("B", only_b)):
        if keys:
            lines.append(f"only in {name} (not compared): {len(keys)} cells")
    return lines


def compare_page(tests: list[Test], run_a: Path, run_b: Path, alpha: float, method: str, notes: list[str]) -> str:
    rows = []
    for t in tests:
        rows.append(
            [
                f"{t.agent} / {t.task}",
                t.metric.replace("_", " "),
                _figure(t.metric, t.a),
                _figure(t.metric, t.b),
                f"{100 * t.difference:+.1f} pp",
                f"{t.n_a} / {t.n_b}",
                t.test,
                f"{t.p:.3g}",
                f"{t.p_adjusted:.3g}",
                t.verdict,
            ]
        )
    header = [
        "agent / task",
        "metric",
        "A",
        "B",
        "B − A",
        "N (A / B)",
        "test",
        "p",
        f"p ({CORRECTIONS[method]})",
        "verdict",
    ]
    table = table_html(header, rows, "compare")
    for verdict in ("better", "worse"):  # colour the verdict cells
        table = table.replace(f"<td>{verdict}</td>", f"<td class='{verdict}'>{verdict}</td>")
    intro = (
        f"<p>B: <code>{html.escape(str(run_b))}</code> against A: <code>{html.escape(str(run_a))}</code>. "
        f"A verdict other than “no detectable change” needs a corrected p-value under {alpha} "
        f"({CORRECTIONS[method]} over all {len(tests)} tests).</p>"
    )
    intro += "".join(f"<p class='warn'>{html.escape(n)}</p>" for n in notes)
    sections = [("Verdict per (agent, task)", verdict_grid(tests)), ("Per (agent, task) and metric", table)]
    return page_html("Comparison of two runs", sections, intro)


#: Cell colours of the verdict grid (Okabe–Ito bluish green and vermillion; grey for no detectable change).
VERDICT_COLOURS = {"better": "#009E73", "worse": "#D55E00", "no detectable change": "#e8e8e8"}


def verdict_grid(tests: list[Test]) -> str:
    """An agents × tasks table of the cells' verdicts (``cell_verdicts``), each with its trial success A -> B."""
    cells = cell_verdicts(tests)
    success = {(t.agent, t.task): t for t in tests if t.metric == "trial_success"}
    tasks = list(dict.fromkeys(t.task for t in tests))
    rows = []
    for agent in agent_order(t.agent for t in tests):
        tds = []
        for task in tasks:
            verdict = cells.get(f"{agent}/{task}")
            if verdict is None:
                tds.append("<td class='absent'>·</td>")
                continue
            t = success[(agent, task)]
            ink = "#000" if verdict == "no detectable change" else "#fff"
            tds.append(
                f"<td class='cell' data-verdict='{verdict}' style='background:{VERDICT_COLOURS[verdict]};"
                f"color:{ink}'>{html.escape(verdict)}<small>{_figure(t.metric, t.a)} → "
                f"{_figure(t.metric, t.b)}</small></td>"
            )
        rows.append(f"<tr><th scope='row'>{html.escape(agent)}</th>{''.join(tds)}</tr>")
    head = "".join(f"<th>{html.escape(task)}</th>" for task in tasks)
    return (
        "<div class='scroll'><table class='heatmap'><caption>A cell is worse if any of its metrics is, else better "
        "if any is (trial success A → B shown)</caption>"
        f"<thead><tr><th></th>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>"
    )


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="evaluate.py compare", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("run_a", type=Path, help="the reference results folder")
    parser.add_argument("run_b", type=Path, help="the results folder compared with it")
    parser.add_argument("--alpha", type=float, default=0.05, help="level of the corrected tests (default 0.05)")
    parser.add_argument("--correction", choices=list(CORRECTIONS), default="holm", help="multiple-test correction")
    parser.add_argument("--out", type=Path, default=None, help="the HTML page (default RUN_B/compare.html)")
    parser.add_argument(
        "--agents",
        default=None,
        metavar="A,B",
        help="compare agent A of RUN_A with agent B of RUN_B, task by task (RUN_A and RUN_B may be one run)",
    )
    args = parser.parse_args(argv)
    if args.agents is not None and len(args.agents.split(",")) != 2:
        parser.error(f"--agents takes two agent names, A,B; got {args.agents!r}")
    if not 0 < args.alpha < 1:
        parser.error(f"--alpha must lie in (0, 1), got {args.alpha}")
    return args


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    try:
        a, b = load(args.run_a), load(args.run_b)
        if args.agents is not None:
            agent_a, agent_b = args.agents.split(",")
            label = f"{agent_a}→{agent_b}"
            a, b = one_agent(a, agent_a, label), one_agent(b, agent_b, label)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    refuse, warn = protocol_differences(a, b)
    if refuse:
        print("error: the runs follow different protocols; a difference would not be the change's:", file=sys.stderr)
        for reason in refuse:
            print(f"  - {reason}", file=sys.stderr)
        return 2
    for note in warn:
        print(f"WARNING: {note}", file=sys.stderr)
    tests = compare(a, b, args.alpha, args.correction)
    only_a = sorted(set(a["metrics"]) - set(b["metrics"]))
    only_b = sorted(set(b["metrics"]) - set(a["metrics"]))
    for line in terminal_lines(tests, args.alpha, args.correction, only_a, only_b):
        print(line)
    out = args.out or args.run_b / "compare.html"
    notes = [f"Warning: {w}" for w in warn] + [
        f"Only in {n}, not compared: {', '.join(k)}" for n, k in (("A", only_a), ("B", only_b)) if k
    ]
    write_atomically(out, compare_page(tests, args.run_a, args.run_b, args.alpha, args.correction, notes))
    print(f"page: {out}")
    return 0
