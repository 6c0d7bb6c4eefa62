"""What ``evaluate.py`` shows people: report.html, one self-contained static page.

The page is built from a results folder alone (results.json, timing.json, videos/, curve_*.png), so any run's
folder can be rendered again (``write_page``).  Everything it shows is inlined — charts as SVG, thumbnails and
learning curves as data URIs, styles in the page — and it runs no script: it opens from disk with no server
and no network.  Videos stay beside it and are linked.

The charts are ``results_figures``'s, inlined as SVG.  The agents × tasks heatmap is an HTML table: one
``td.cell`` per (agent, task) that ran, its trial success and 95 % Wilson interval.
"""

from __future__ import annotations

import base64
import html
import json
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation.report import describe_seeds
from panda_grasp_env.commands.results_figures import (
    FAMILY_COLOURS,
    agent_order,
    failures_figure,
    family,
    pair_order,
    split_key,
    success_figure,
    svg,
)
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json
from panda_grasp_env.tooling.runs import write_atomically

# --- the heatmap ---------------------------------------------------------------------------------------------


def _shade(fraction: float) -> tuple[str, str]:
    """(background, text colour) for a rate in [0, 1] on matplotlib's viridis (perceptually uniform)."""
    from matplotlib import colormaps
    from matplotlib.colors import to_hex

    rgba = colormaps["viridis"](float(np.clip(fraction, 0.0, 1.0)))
    luminance = 0.2126 * rgba[0] + 0.7152 * rgba[1] + 0.0722 * rgba[2]
    return to_hex(rgba), "#000" if luminance > 0.45 else "#fff"


def success_cells(table: dict[str, dict]) -> dict[tuple[str, str], dict[str, Any]]:
    """(agent, task) -> its trial success (``rate``-shaped: rate, successes, n, ci95) from a metrics table."""
    return {split_key(key): m["trial_success"] for key, m in table.items()}


def _grid_table(
    agents: list[str],
    tasks: list[str],
    cell: Callable[[str, str], str],
    row_head: Callable[[str], str],
    kind: str,
    caption: str,
) -> str:
    """An agents × ``tasks`` HTML table: ``cell(agent, task)`` gives each ``<td>``, ``row_head(agent)`` each row's
    heading; ``kind`` is the table's CSS class after ``heatmap``."""
    head = "".join(f"<th scope='col'>{html.escape(t)}</th>" for t in tasks)
    rows = [
        f"<tr><th scope='row'>{row_head(agent)}</th>{''.join(cell(agent, task) for task in tasks)}</tr>"
        for agent in agents
    ]
    return (
        f"<table class='heatmap{kind}'><caption>{html.escape(caption)}</caption>"
        f"<thead><tr><th></th>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
    )


def heatmap_html(
    cells: dict[tuple[str, str], dict[str, Any]],
    tasks: list[str],
    agents: Iterable[str] = (),
    absent: Callable[[str, str], str] = lambda agent, task: "not run",
    caption: str = "Trial success (95 % Wilson interval, n) of each agent on each task",
) -> str:
    """An agents × ``tasks`` table of trial success: one ``td.cell`` per (agent, task) in ``cells`` (a rate:
    successes, n, ci95), shaded by its rate, with its interval; other pairs (of ``agents`` too, which may
    have no cell) are grey ``td.absent`` cells whose tooltip is ``absent(agent, task)``."""

    def cell(agent: str, task: str) -> str:
        r = cells.get((agent, task))
        if r is None:
            return f"<td class='absent' title='{html.escape(absent(agent, task))}'>·</td>"
        low, high = r["ci95"]
        background, ink = _shade(r["rate"])
        tip = html.escape(
            f"{agent} on {task}: {r['successes']}/{r['n']} trials succeeded, "
            f"95 % interval {100 * low:.0f}–{100 * high:.0f} %"
        )
        return (
            f"<td class='cell' data-agent='{html.escape(agent)}' data-task='{html.escape(task)}' "
            f"data-rate='{r['rate']}' title='{tip}' style='background:{background};color:{ink}'>"
            f"{100 * r['rate']:.0f} %<small>{100 * low:.0f}–{100 * high:.0f} · n {r['n']}</small></td>"
        )

    def row_head(agent: str) -> str:
        return f"<span class='swatch' style='background:{FAMILY_COLOURS[family(agent)]}'></span>{html.escape(agent)}"

    caption += "; shade from dark purple (0 %) to yellow (100 %), grey: not run (hover for why)"
    return _grid_table(agent_order([*agents, *(agent for agent, _ in cells)]), tasks, cell, row_head, "", caption)


def published_cells(markdown: str) -> dict[tuple[str, str], dict[str, Any]]:
    """(agent, task) -> trial success (``rate``-shaped) read from the first results table in ``markdown``: the
    table evaluate.py writes into report.md (columns agent, task, N, "trial success (95 % CI)", ...), as the
    docs publish it (agent names may be bold and tagged "(learned)").  The counts are exact: a whole percent
    of N <= 100 episodes names one count; the interval is Wilson's, recomputed from them."""
    from panda_grasp_env.agents.evaluation.metrics import rate

    cells, in_table = {}, False
    for line in markdown.splitlines():
        columns = [c.strip() for c in line.strip().strip("|").split("|")]
        if columns[:4] == ["agent", "task", "N", "trial success (95 % CI)"]:
            in_table = True
        elif in_table and not line.startswith("|"):
            break
        elif in_table and not set(columns[0]) <= set("-: "):
            agent = columns[0].replace("*", "").removesuffix("(learned)").strip()
            n, percent = int(columns[2]), float(columns[3].split("%")[0])
            if n > 100:
                raise ValueError(f"{agent}/{columns[1]}: {n} episodes; a whole percent does not name the count")
            cells[(agent, columns[1])] = rate(round(percent * n / 100), n)
    if not cells:
        raise ValueError("no results table (| agent | task | N | trial success (95 % CI) | ...) found")
    return cells


# --- pieces of the page ----------------------------------------------------------------------------------------


def data_uri(data: bytes, mime: str) -> str:
    return f"data:{mime};base64,{base64.b64encode(data).decode()}"


def thumbnail(video: Path, width: int = 192) -> str | None:
    """A JPEG data URI of the frame two thirds into ``video`` (the action, not the still start), or None if it
    cannot be read."""
    import cv2
    import imageio.v3 as iio

    try:
        frames = list(iio.imiter(video))
    except (OSError, ValueError, RuntimeError):
        return None
    if not frames:
        return None
    frame = frames[(2 * len(frames)) // 3]
    height = round(frame.shape[0] * width / frame.shape[1])
    small = cv2.resize(frame, (width, height), interpolation=cv2.INTER_AREA)
    ok, jpeg = cv2.imencode(".jpg", cv2.cvtColor(small, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 70])
    return data_uri(jpeg.tobytes(), "image/jpeg") if ok else None


def table_html(header: list[str], rows: list[list[str]], cls: str = "plain") -> str:
    """A plain HTML table; cells are escaped text."""
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>" for row in rows)
    return f"<table class='{cls}'><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def counts_text(counts: dict[str, int]) -> str:
    return ", ".join(f"{reason} {n}" for reason, n in counts.items()) or "—"


#: The heatmap's styles (the docs' Results page uses them too).
HEATMAP_STYLE = """
.results-heatmap,.scroll{overflow-x:auto}table.heatmap th{white-space:nowrap}
table.heatmap td{text-align:center;min-width:4.2rem;font-weight:600}
table.heatmap td small{display:block;font-weight:400;font-size:.7rem;opacity:.85;white-space:nowrap}
table.heatmap td.absent{background:#f3f3f3;color:#bbb}
.swatch{display:inline-block;width:.7rem;height:.7rem;margin-right:.4rem;border-radius:2px}
"""
STYLE = (
    HEATMAP_STYLE
    + """
body{font:14px/1.45 system-ui,sans-serif;margin:1.5rem auto;max-width:1200px;padding:0 1rem;color:#222}
h1{font-size:1.5rem}h2{font-size:1.2rem;margin-top:2rem;border-bottom:1px solid #ddd}
table{border-collapse:collapse;margin:.5rem 0}th,td{padding:.25rem .5rem;border:1px solid #ddd;text-align:left}
caption{text-align:left;color:#555;padding:.25rem 0}
svg{max-width:100%;height:auto}
.clips{display:flex;flex-wrap:wrap;gap:.75rem}.clips figure{margin:0;width:192px;font-size:.75rem}
.clips img{display:block;width:192px;border:1px solid #ccc}
.better{color:#0a7a2f;font-weight:600}.worse{color:#b00020;font-weight:600}.warn{background:#fff3cd;padding:.5rem}
"""
)


def page_html(title: str, sections: list[tuple[str, str]], intro: str = "") -> str:
    """A whole static page: ``sections`` are (heading, HTML body) pairs."""
    body = "".join(f"<section><h2>{html.escape(h)}</h2>{content}</section>" for h, content in sections)
    return (
        "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width,initial-scale=1'>"
        f"<title>{html.escape(title)}</title><style>{STYLE}</style></head>"
        f"<body><h1>{html.escape(title)}</h1>{intro}{body}</body></html>\n"
    )


def legend_html() -> str:
    return " ".join(
        f"<span><span class='swatch' style='background:{c}'></span>{f}</span>" for f, c in FAMILY_COLOURS.items()
    )


def _per_pair_table(table: dict[str, dict], timing: dict[str, dict]) -> str:
    rows = []
    for key in pair_order(table):
        m, t = table[key], timing.get(key, {})
        agent, task = split_key(key)
        ms = t.get("ms_per_decision")
        rows.append(
            [
                agent,
                task,
                m["episodes"],
                counts_text(m.get("episode_failures", {})),
                counts_text(m["failures"]),
                "—" if ms is None else f"{ms:.1f}",
                "—" if "wall_seconds_per_episode" not in t else f"{t['wall_seconds_per_episode']:.1f}",
            ]
        )
    header = [
        "agent",
        "task",
        "N",
        "failed episodes, why",
        "failed actions",
        "ms / decision (median)",
        "wall s / episode",
    ]
    return table_html(header, rows)


def _decision_heatmap(table: dict[str, dict], timing: dict[str, dict], tasks: list[str]) -> str:
    """ms per decision per (agent, task), shaded on a log scale (1 ms .. 10 s)."""
    cells = {split_key(key): timing[key]["ms_per_decision"] for key in table if key in timing}

    def cell(agent: str, task: str) -> str:
        ms = cells.get((agent, task))
        if ms is None:
            return "<td class='absent'>·</td>"
        background, ink = _shade(1 - np.clip(np.log10(max(ms, 1e-3)) / 4, 0, 1))
        return f"<td style='background:{background};color:{ink}'>{ms:.3g}</td>"

    caption = "Median milliseconds per decision (darker: slower; wall clock, so it depends on the machine and its load)"
    return _grid_table(agent_order(a for a, _ in cells), tasks, cell, html.escape, " decisions", caption)


def _clips(out: Path, table: dict[str, dict]) -> str:
    figures = []
    for key in pair_order(table):
        agent, task = split_key(key)
        video = out / "videos" / f"{agent}_{task}.mp4"
        if not video.exists():
            continue
        image = thumbnail(video)
        picture = f"<img src='{image}' alt='{html.escape(key)}' loading='lazy'>" if image else "(unreadable video)"
        figures.append(
            f"<figure><a href='videos/{html.escape(video.name)}'>{picture}</a>"
            f"<figcaption>{html.escape(agent)} / {html.escape(task)}</figcaption></figure>"
        )
    if not figures:
        return "<p>No videos in this run (<code>--no-video</code>).</p>"
    return (
        f"<p>Each picture links to its video (the first seed, replayed).</p><div class='clips'>{''.join(figures)}</div>"
    )


def _curves(out: Path) -> str:
    parts = []
    for curve in sorted(out.glob("curve_*.png")):
        name = curve.stem.removeprefix("curve_")
        parts.append(
            f"<h3>{html.escape(name)}</h3><img alt='learning curve of {html.escape(name)}' "
            f"style='max-width:100%' src='{data_uri(curve.read_bytes(), 'image/png')}'>"
        )
        parts.append(seeds_section(name))
    return "".join(parts)


def seeds_section(checkpoint: str) -> str:
    """The checkpoint's figures over training seeds (``seeds.json`` beside its card, from ``train.py --seeds``),
    or nothing if it has none."""
    from panda_grasp_env.agents.policies.learned import CHECKPOINTS

    path = CHECKPOINTS / checkpoint / "seeds.json"
    if not path.is_file():
        return ""
    from panda_grasp_env.agents.learning.seed_figures import study_html

    return study_html(read_json(path, MAX_DOCUMENT_BYTES))


def _protocol(results: dict[str, Any]) -> str:
    protocol, provenance = results["protocol"], results.get("provenance", {})
    seeds = {t: describe_seeds(s) for t, s in protocol["seeds"].items()}
    rows = [
        ["protocol", "full" if protocol.get("full") else "quick"],
        ["seeds per (agent, task)", json.dumps(seeds)],
        ["options on top of each task's", json.dumps(protocol.get("task_options") or {}) or "none"],
        ["env ids", json.dumps(protocol.get("env_ids", {}))],
        ["commit", provenance.get("commit", "not recorded")],
        *(
            [f"imported {f['module']}", f"{f['file']}, SHA-256 {f['sha256']}"]
            for f in protocol.get("imports", [])
            if isinstance(f, dict)  # records before files were named hold bare module names
        ),
        ["versions", ", ".join(f"{k} {v}" for k, v in provenance.get("versions", {}).items()) or "not recorded"],
        ["machine", provenance.get("machine", "not recorded")],
    ]
    skipped = protocol.get("skipped", {})
    text = table_html(["", ""], rows)
    if skipped:
        text += (
            f"<details><summary>{len(skipped)} (agent, task) pairs skipped: they do not apply</summary>"
            + table_html(["pair", "why"], [[k, v] for k, v in skipped.items()])
            + "</details>"
        )
    return text


def build_page(out: Path) -> str:
    """report.html's text for the results folder ``out`` (results.json, timing.json, videos/, curve_*.png)."""
    results = read_json(out / "results.json", MAX_DOCUMENT_BYTES)
    timing = read_json(out / "timing.json", MAX_DOCUMENT_BYTES) if (out / "timing.json").is_file() else {}
    table = results["metrics"]
    tasks = results["protocol"]["tasks"]
    skipped = results["protocol"].get("skipped", {})
    heatmap = heatmap_html(
        success_cells(table),
        tasks,
        results["protocol"]["agents"],
        lambda a, t: f"skipped: {skipped.get(f'{a}/{t}', 'not run')}",
    )
    episodes = sum(m["episodes"] for m in table.values())
    kind = "Full" if results["protocol"].get("full") else "Quick"
    intro = (
        f"<p>{episodes} episodes of {len(table)} (agent, task) pairs through the same <code>env.step</code> "
        f"loop. Agent families: {legend_html()}.</p>"
    )
    sections = [
        ("Trial success", f"<div class='scroll'>{heatmap}</div>"),
        ("Trial success per task", svg(success_figure(table))),
        ("Failures", svg(failures_figure(table)) + _per_pair_table(table, timing)),
        ("Decision time", f"<div class='scroll'>{_decision_heatmap(table, timing, tasks)}</div>"),
        ("Clips", _clips(out, table)),
    ]
    curves = _curves(out)
    if curves:
        sections.append(("Learned policies: learning curves and figures over training seeds", curves))
    sections.append(("Protocol", _protocol(results)))
    return page_html(f"{kind} benchmark", sections, intro)


def write_page(out: Path) -> Path:
    """Write ``out``/report.html (``build_page``); returns its path."""
    path = out / "report.html"
    write_atomically(path, build_page(out))
    return path
