"""MkDocs hooks: a source tree laid out as the package installs (for the API reference), one page per
registered id generated from the env itself, one page per checkpoint card (with its figures), the
Environments page's table of env options (from their one declaration, ``EnvOptions``) and the Results page's
heatmaps.

``agents/`` and ``perception/`` install as ``panda_grasp_env.agents`` and ``panda_grasp_env.perception``
(pyproject's package-dir); griffe reads sources by path, so it is given ``build/api-src/panda_grasp_env``:
links to ``panda_grasp_env/``'s entries plus ``agents`` and ``perception``."""

from __future__ import annotations

import ast
import inspect
import re
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TREE = ROOT / "build" / "api-src" / "panda_grasp_env"
#: Nav sections (titles in mkdocs.yml) whose pages ``on_config`` lists.
ENV_IDS_SECTION = "Env ids (generated from the envs themselves)"
CARDS_SECTION = "Checkpoint cards"
#: Replaced in index.md by a link to every registered id's page.
ENV_ID_LINKS = "<!-- env id links -->"
#: Replaced in environments.md by the table of env options.
ENV_OPTIONS_TABLE = "<!-- env options table -->"
#: Replaced in results.md by the heatmaps of the published quick results and of the checkpoints' held-out tests.
QUICK_RESULTS = "<!-- quick results heatmap -->"
HELD_OUT_RESULTS = "<!-- held-out results heatmap -->"


def checkpoint_folders() -> list[Path]:
    """Every shipped checkpoint's folder (learned policies, then fall-dynamics models)."""
    return sorted((ROOT / "agents" / "checkpoints").glob("*/card.md")) + sorted(
        (ROOT / "agents" / "learning" / "falls" / "checkpoints").glob("*/card.md")
    )


def on_startup(**kwargs: object) -> None:
    shutil.rmtree(TREE, ignore_errors=True)
    TREE.mkdir(parents=True)
    for entry in (ROOT / "panda_grasp_env").iterdir():
        if entry.name != "__pycache__":
            (TREE / entry.name).symlink_to(entry)
    for folder in ("agents", "perception"):
        (TREE / folder).symlink_to(ROOT / folder)


def env_page(env_id: str) -> str:
    """A reference page for one registered id, read from the env itself: its defaults, the spaces of its
    default modes, its task's options and the ``info`` keys a reset and a step report."""
    import inspect

    import gymnasium as gym

    from panda_grasp_env.registration import ENV_IDS, TASKS

    defaults, max_steps = ENV_IDS[env_id]
    env = gym.make(f"panda_grasp_env:{env_id}")
    try:
        _, reset_info = env.reset(seed=0)
        env.action_space.seed(0)
        step_info = env.step(env.action_space.sample())[4]
    finally:
        env.close()
    task = TASKS[defaults["task"]]
    options = [p for p in inspect.signature(task.__init__).parameters.values() if p.name not in ("self", "kwargs")]
    lines = [
        f"# {env_id}",
        "",
        (inspect.getdoc(task) or "").split("\n\n")[0],
        "",
        "```python",
        f'env = gym.make("panda_grasp_env:{env_id}")',
        "```",
        "",
        "| | |",
        "|---|---|",
        f"| task | `{defaults['task']}` (`{task.__module__}`) |",
        f"| registered options | `{ {k: v for k, v in defaults.items() if k != 'task'} }` |",
        f"| max_episode_steps | {max_steps} |",
        f"| default action space | `{env.action_space}` |",
        f"| default observation space | `{env.observation_space}` |",
        "",
        "## Task options (`gym.make` keyword arguments)",
        "",
        *[f"- `{p.name}` (default `{p.default!r}`)" for p in options],
        "",
        "Env options (modes, cameras, sizes, scene) are the same for every id: see [Environments](../environments.md).",
        "",
        "## `info` keys",
        "",
        f"- after `reset`: {', '.join(f'`{k}`' for k in sorted(reset_info))}",
        f"- after `step`: {', '.join(f'`{k}`' for k in sorted(step_info))}",
        "",
    ]
    return "\n".join(lines)


def attribute_docstrings(path: Path, class_name: str) -> dict[str, str]:
    """The docstrings under the annotated attributes of class ``class_name`` in ``path`` (as griffe reads them
    for the API reference; Python keeps none at run time), by attribute name."""
    tree = ast.parse(path.read_text())
    body = next(node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == class_name).body
    return {
        field.target.id: inspect.cleandoc(doc.value.value)
        for field, doc in zip(body, body[1:])
        if isinstance(field, ast.AnnAssign) and isinstance(field.target, ast.Name)
        if isinstance(doc, ast.Expr) and isinstance(doc.value, ast.Constant) and isinstance(doc.value.value, str)
    }


def env_options_table() -> str:
    """Every env option with its type, default and docstring: ``PandaEnv``'s signature (read from
    ``EnvOptions``) and ``EnvOptions``' field docstrings."""
    from panda_grasp_env.env import PandaEnv
    from panda_grasp_env.env_options import ENV_OPTIONS

    docs = attribute_docstrings(ROOT / "panda_grasp_env" / "env_options.py", "EnvOptions")
    parameters = inspect.signature(PandaEnv).parameters
    rows = ["| option | type | default | what it does |", "|---|---|---|---|"]
    for name in ENV_OPTIONS:
        parameter = parameters[name]
        kind = re.sub(r"\b[a-z_][\w.]*\.(?=[A-Z])", "", inspect.formatannotation(parameter.annotation))  # bare names
        doc = " ".join(docs[name].split()).replace("|", "\\|")  # a pipe in text would end the cell
        rows.append(f"| `{name}` | `{kind}` | `{parameter.default!r}` | {doc} |")
    return "\n".join(rows)


def on_config(config, **kwargs):  # MkDocs hook: the signature is MkDocs'
    """List the generated pages in the nav: every registered id, every checkpoint card."""
    from panda_grasp_env.registration import ENV_IDS

    pages = {
        ENV_IDS_SECTION: [{env_id: f"ids/{env_id}.md"} for env_id in ENV_IDS],
        CARDS_SECTION: [
            {card.parent.name: f"checkpoints/{card.parent.name}/index.md"} for card in checkpoint_folders()
        ],
    }
    for item in config["nav"]:
        for title in pages:
            if isinstance(item, dict) and title in item:
                item[title] = pages[title]
    return config


def results_heatmaps() -> dict[str, str]:
    """The Results page's heatmaps by marker: the quick table that benchmark.md publishes, and the held-out
    final tests of the shipped checkpoints (their final.json)."""
    import json

    from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
    from panda_grasp_env.commands.results_page import HEATMAP_STYLE, heatmap_html, published_cells

    quick = published_cells((ROOT / "docs" / "benchmark.md").read_text())
    tasks = [t for t in BENCHMARKS if any(task == t for _, task in quick)]
    held_out = {}
    for card in sorted((ROOT / "agents" / "checkpoints").glob("*/card.md")):
        task = json.loads((card.parent / "checkpoint.json").read_text())["task"]
        final = json.loads((card.parent / "final.json").read_text())
        held_out[(card.parent.name, task)] = final["metrics"]["trial_success"]
    return {
        QUICK_RESULTS: f"<style>{HEATMAP_STYLE}</style>"
        + heatmap_html(quick, tasks, caption="Quick protocol: trial success (95 % Wilson interval, n)"),
        HELD_OUT_RESULTS: heatmap_html(
            held_out,
            [t for t in BENCHMARKS if any(task == t for _, task in held_out)],
            caption="Held-out final tests: trial success (95 % Wilson interval, n)",
        ),
    }


def on_page_markdown(markdown, page, config, files, **kwargs):  # MkDocs hook: the signature is MkDocs'
    """The home page's list of id pages, from the registry (a hand-kept list missed new ids); the Environments
    page's table of env options; the Results page's heatmaps."""
    from panda_grasp_env.registration import ENV_IDS

    if page.file.src_uri == "environments.md":
        if ENV_OPTIONS_TABLE not in markdown:
            raise ValueError(f"docs/environments.md lost its {ENV_OPTIONS_TABLE} marker")
        return markdown.replace(ENV_OPTIONS_TABLE, env_options_table())

    if page.file.src_uri == "results.md":
        for marker, table in results_heatmaps().items():
            if marker not in markdown:
                raise ValueError(f"docs/results.md lost its {marker} marker")
            markdown = markdown.replace(marker, f"<div class='results-heatmap'>{table}</div>")
        return markdown
    if page.file.src_uri != "index.md":
        return markdown
    if ENV_ID_LINKS not in markdown:
        raise ValueError(f"docs/index.md lost its {ENV_ID_LINKS} marker")
    return markdown.replace(ENV_ID_LINKS, ", ".join(f"[{env_id}](ids/{env_id}.md)" for env_id in ENV_IDS))


def on_files(files, config, **kwargs):  # MkDocs hook: the signature is MkDocs'
    """One generated page per registered id under ``ids/``; each checkpoint's card and figures under
    ``checkpoints/<name>/``."""
    from mkdocs.structure.files import File

    from panda_grasp_env.registration import ENV_IDS

    for env_id in ENV_IDS:
        files.append(File.generated(config, f"ids/{env_id}.md", content=env_page(env_id)))
    for card in checkpoint_folders():
        folder = f"checkpoints/{card.parent.name}"
        files.append(File.generated(config, f"{folder}/index.md", content=card.read_text()))
        for figure in sorted(card.parent.rglob("*.png")):
            path = f"{folder}/{figure.relative_to(card.parent).as_posix()}"
            files.append(File.generated(config, path, abs_src_path=str(figure)))
    return files
