"""What a training run leaves behind, and how it ships: the evaluation log, the learning curve, the best
policy (as data: ``policy_files``), the model card, and the shipped checkpoint folder (with, attached, its
config's figures over training seeds: ``attach_study``)."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path
from typing import Any

import yaml

from panda_grasp_env.agents.evaluation.metrics import describe_rate
from panda_grasp_env.agents.evaluation.protocol import is_low_level, task_label
from panda_grasp_env.agents.learning.config import HEIGHTMAP_ALGORITHMS, TrainConfig, load_run, steps_label
from panda_grasp_env.agents.learning.imitation import Demonstrations
from panda_grasp_env.agents.learning.policy_files import load_policy, policy_paths, save_policy
from panda_grasp_env.agents.learning.seed_figures import study_markdown
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.agents.policies.learned import SHIPPED_FILES
from panda_grasp_env.agents.policies.policy_agent import ACTING_RULES, check_acting_rules
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, MAX_LOG_BYTES, read_json, read_json_lines
from panda_grasp_env.tooling.runs import atomic_path, resume_summary, write_atomically, write_json


def read_evaluations(run_dir: Path) -> list[dict[str, Any]]:
    path = run_dir / "evaluations.jsonl"
    if not path.exists():
        return []
    return [record for _, record in read_json_lines(path, MAX_LOG_BYTES)]


def plot_curve(run_dir: Path, title: str, steps: str = "environment steps") -> None:
    """curve.png: evaluation success (95 % CI band) against ``steps`` (what the run's steps count) and against
    wall time; a structure task's success per tier beside it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = read_evaluations(run_dir)
    if not rows:
        return
    done = [r["steps"] for r in rows]
    minutes = [r["wall_seconds"] / 60 for r in rows]
    figure, axes = plt.subplots(1, 2, figsize=(10, 3.6), sharey=True)
    for axis, x, label in ((axes[0], done, steps), (axes[1], minutes, "wall time, minutes")):
        success = [r["metrics"]["trial_success"]["rate"] for r in rows]
        low = [r["metrics"]["trial_success"]["ci95"][0] for r in rows]
        high = [r["metrics"]["trial_success"]["ci95"][1] for r in rows]
        axis.plot(x, success, marker="o", label="trial success")
        axis.fill_between(x, low, high, alpha=0.2)
        if any(r["metrics"]["grasp_success"]["n"] for r in rows):
            axis.plot(x, [r["metrics"]["grasp_success"]["rate"] for r in rows], marker="s", label="grasp success")
            axis.plot(x, [r["metrics"]["action_efficiency"] for r in rows], marker="^", label="action efficiency")
        tiers = sorted({tier for r in rows for tier in r["metrics"].get("trial_success_by_tier", {})}, key=int)
        for tier in tiers:  # a structure task's validation success per tier (dashed)
            by_tier = [r["metrics"].get("trial_success_by_tier", {}).get(tier) for r in rows]
            points = [(xi, t["rate"]) for xi, t in zip(x, by_tier) if t is not None]
            axis.plot(*zip(*points), linestyle="--", marker=".", label=f"tier {tier} success")
        axis.set_xlabel(label)
        axis.set_ylim(-0.02, 1.02)
        axis.grid(alpha=0.3)
    axes[0].set_ylabel("rate")
    handles, labels = axes[0].get_legend_handles_labels()
    figure.suptitle(title)
    figure.tight_layout(rect=(0, 0.08, 1, 1))  # the legend sits in a strip below the plots, over no point
    figure.legend(handles, labels, loc="lower center", ncol=len(labels), frameon=False)
    with atomic_path(run_dir / "curve.png") as tmp:
        figure.savefig(tmp, dpi=100, format="png")
    plt.close(figure)


#: How a run's tested policy was chosen (``best.json`` ``chosen_by``), as its card says it.
CHOSEN_BY = {
    "validation": "the best of the periodic validation evaluations (seeds {first}-{last}), from step {best} of {steps}",
    "selection": "the one from step {best} of {steps}, chosen over the best periodic validation's on selection seeds "
    "(further validation episodes, never the test seeds)",
    "final": "the final one (step {steps}): this run kept no validated best",
}


def save_best_policy(
    policy: Any, run_dir: Path, steps: int, chosen_by: str = "validation", selection: dict[str, Any] | None = None
) -> None:
    """best_policy.safetensors + best_policy.json (the policy alone, as data: ``policy_files``) and best.json.

    ``chosen_by``: ``validation`` (the best periodic evaluation so far), ``final`` (no tracked best) or
    ``selection`` (a policy that beat the validated best on further validation episodes, the selection seeds
    ``eval_seed + SELECTION_SEED_OFFSET`` ...).  ``selection``: both policies' figures there, when they were
    compared (``training.select_on_selection_seeds``)."""
    if chosen_by not in CHOSEN_BY:
        raise ValueError(f"chosen_by={chosen_by!r}: expected one of {list(CHOSEN_BY)}")
    save_policy(policy, run_dir / "best_policy")
    write_best_record(run_dir, steps, chosen_by, selection)


def write_best_record(run_dir: Path, steps: int, chosen_by: str, selection: dict[str, Any] | None = None) -> None:
    """best.json alone: the best policy's step, how it was chosen and any selection figures (its weights are
    already saved)."""
    write_json(
        run_dir / "best.json",
        {"steps": steps, "chosen_by": chosen_by, **({"selection": selection} if selection else {})},
    )


def load_best_policy(run_dir: Path) -> tuple[Any, dict[str, Any]]:
    """The best validated policy of a run (or of a shipped checkpoint, where it is ``policy.*``) and its
    facts (steps, how it was chosen); nothing is unpickled."""
    stem = run_dir / "best_policy"
    if not policy_paths(stem)[0].is_file() and policy_paths(run_dir / "policy")[0].is_file():
        stem = run_dir / "policy"
    if not policy_paths(stem)[0].is_file():
        raise ValueError(
            f"cannot load the best policy of {run_dir}: no best_policy.json (a run saved before "
            f"policies were stored as data keeps a pickled best_policy.zip, which is not loaded)"
        )
    try:
        best = read_json(run_dir / "best.json", 1 << 20)
    except ValueError as error:
        raise ValueError(f"cannot load the best policy of {run_dir}: {error}") from None
    if not isinstance(best, dict):
        raise ValueError(f"cannot load the best policy of {run_dir}: best.json is not a JSON mapping")
    try:
        return load_policy(stem), best
    except ValueError as error:
        raise ValueError(f"cannot load the best policy of {run_dir}: {error}") from None


def earlier_tests(run_dir: Path, best_steps: int, steps: int) -> list[dict[str, Any]]:
    """The earlier final tests of the same policy (a retest keeps what it replaces, newest last): each its
    commit and metrics.  Empty when there is none or the last one tested another policy."""
    path = run_dir / "final.json"
    if not path.is_file():
        return []
    previous = read_json(path, MAX_DOCUMENT_BYTES)
    if (previous.get("best_steps"), previous.get("steps")) != (best_steps, steps):
        return []
    test = {"test_commit": previous.get("test_commit"), "metrics": previous["metrics"]}
    test |= {rule: True for rule in ACTING_RULES if previous.get(rule)}
    return [*previous.get("earlier", []), test]


def demonstrations_summary(config: TrainConfig) -> str:
    """The card's line on the demonstrations a run learned from ('' if none)."""
    if "demonstrations" not in config.algo_kwargs:
        return ""
    spec = Demonstrations.of(config.algo_kwargs["demonstrations"])
    kind = "successful " if spec.successful_only else ""
    return f"the first {spec.episodes} {kind}episodes of Minari dataset `{spec.dataset}`"


def model_card(config: TrainConfig, run_dir: Path, final: dict[str, Any], name: str | None = None) -> str:
    """The model card (markdown) of a run or shipped checkpoint folder; ``name``: the checkpoint's name, when it
    was shipped under another name than its run's (``config.name``)."""
    meta = read_json(run_dir / "meta.json", MAX_DOCUMENT_BYTES)
    m = final["metrics"]
    low_level = is_low_level(config.env_id, config.env_kwargs)

    def pct(r: dict[str, Any]) -> str:
        if r["n"] == 0:
            return "- (none attempted)"
        return describe_rate(r)

    def results(m: dict[str, Any]) -> list[str]:
        if low_level:  # one goal per episode: trial success says it all
            return [f"- trial success: {pct(m['trial_success'])}"]
        return [
            f"- trial success: {pct(m['trial_success'])}",
            f"- completion: {pct(m['completion'])}",
            f"- grasp success: {pct(m['grasp_success'])}",
            f"- action efficiency: {100 * m['action_efficiency']:.1f} %",
            *(
                [f"- collateral: {m['collateral_per_action']:.2f} disturbed objects per action"]
                if "collateral_per_action" in m
                else []
            ),
            f"- failures: {json.dumps(m['failures'])}",
            *([f"- failed episodes, why: {json.dumps(m['episode_failures'])}"] if "episode_failures" in m else []),
        ]

    earlier = []
    for test in reversed(final.get("earlier", [])):
        rules = acting_rules_text(test)
        earlier += [
            "",
            f"At commit {test['test_commit']}{f', with {rules}' if rules else ''}:",
            "",
            *results(test["metrics"]),
        ]
    if earlier:
        earlier = ["", "### Earlier tests of this policy, same seeds (newest first)", *earlier]

    lines = [
        f"# {name or config.name}",
        "",
        *([f"Shipped from the run `{config.name}`.", ""] if name not in (None, config.name) else []),
        f"`{config.algo}` on `{config.env_id}` ({json.dumps(config.env_kwargs)}"
        + (f"; training envs also {json.dumps(config.train_env_kwargs)}" if config.train_env_kwargs else "")
        + "), trained by this repository's `train.py` with the resolved config below.",
        "",
        "| | |",
        "|---|---|",
        f"| seed | {config.seed} |",
        f"| {steps_label(config)} | {final['steps']} |",
        *([f"| demonstrations | {demos} |"] if (demos := demonstrations_summary(config)) else []),
        *([f"| sessions | {resumed} |"] if (resumed := resume_summary(meta)) else []),
        f"| wall time | {final['wall_seconds'] / 60:.1f} min ({final['steps_per_second']} steps/s, evaluations included) |",
        f"| machine | {meta['machine']} |",
        f"| commit | {meta['commit']} |",
        *(
            [f"| final test at commit | {tested} |"]
            if (tested := final.get("test_commit", meta["commit"])) != meta["commit"]
            else []
        ),
        f"| versions | {', '.join(f'{k} {v}' for k, v in meta['versions'].items())} |",
        "| steps to 90 % validation success | "
        + (
            "not reached |"
            if final["steps_to_90_percent"] is None
            else f"{final['steps_to_90_percent']} ({final['minutes_to_90_percent']} min) |"
        ),
        "",
        f"## Final test: {m['episodes']} episodes on held-out seeds {final['test_seeds'][0]}-{final['test_seeds'][1]}",
        "",
        "The policy tested is "
        + CHOSEN_BY[final["chosen_by"]].format(
            first=config.eval_seed,
            last=config.eval_seed + config.eval_episodes - 1,
            best=final["best_steps"],
            steps=final["steps"],
        )
        + ".",
        *(
            [
                "",
                f"Before the test, on {s['episodes']} selection episodes (seeds {s['seeds'][0]}-{s['seeds'][1]}), the "
                f"validated best (step {s['validated_best']['steps']}) held {pct(s['validated_best']['trial_success'])} "
                f"and the final policy (step {s['final']['steps']}) {pct(s['final']['trial_success'])}.",
            ]
            if (s := final.get("selection"))
            else []
        ),
        *(
            [
                "",
                f"It acts as shipped, with {rules_on} (`checkpoint.json` "
                f"{', '.join(f'`{rule}`' for rule in ACTING_RULES if final.get(rule))}, chosen on selection seeds; the "
                "rules: `panda_grasp_env.agents.learning.acting_rules`).",
            ]
            if (rules_on := acting_rules_text(final))
            else []
        ),
        "",
        *results(m),
        *earlier,
        "",
        "![learning curve](curve.png)",
        "",
        *seeds_section(run_dir),
        "## Config" + (" (as of the last session)" if meta.get("resumed") else ""),
        "",
        "```yaml",
        yaml.safe_dump(dataclasses.asdict(config), sort_keys=False).rstrip(),
        "```",
        "",
    ]
    return "\n".join(lines)


def acting_rules_text(test: dict[str, Any]) -> str:
    """The acting rules a test's record has on, as the card names them ("its `FailureMemory` and
    `FaceCentring`"); '' if none."""
    return " and ".join(text for rule, text in ACTING_RULES.items() if test.get(rule))


def seeds_section(folder: Path) -> list[str]:
    """The card's section on the config's figures over training seeds (seeds.json, from ``train.py --seeds``
    attached with ``attach_study``), or nothing."""
    if not (folder / "seeds.json").is_file():
        return []
    study = read_json(folder / "seeds.json", MAX_DOCUMENT_BYTES)
    return ["## Over training seeds", "", study_markdown(study), "", "![performance profile](seeds_profile.png)", ""]


def ship(run_dir: Path, name: str, **acting: bool) -> Path:
    """Copy a finished run (policy, card, curve, config) to ``agents/checkpoints/<name>`` (``learned.CHECKPOINTS``),
    atomically.  ``acting``: the rules the checkpoint acts by, each on or off (``ACTING_RULES``:
    ``avoid_failures=True`` ships it with a ``FailureMemory``; ``Checkpoint.acting``; heightmap Q-policies
    only)."""
    run_dir = Path(run_dir)
    missing = [f for f in SHIPPED_FILES if not (run_dir / f).is_file()]
    if missing:
        raise ValueError(f"{run_dir} is not a finished run: {missing} missing (train it until it stops first)")
    if not name.replace("-", "").replace("_", "").isalnum():
        raise ValueError(f"checkpoint name {name!r}: letters, digits, - and _ only")
    config = load_run(run_dir)
    check_acting_rules(acting)
    acting = {rule: bool(acting.get(rule, False)) for rule in ACTING_RULES}
    if any(acting.values()) and config.algo not in HEIGHTMAP_ALGORITHMS:
        on = [rule for rule, value in acting.items() if value]
        raise ValueError(f"{', '.join(on)}: only heightmap_dqn policies act by these rules, {run_dir} is {config.algo}")
    best = read_json(run_dir / "best.json", MAX_DOCUMENT_BYTES)
    staging = learned.CHECKPOINTS / f".{name}.tmp"
    shutil.rmtree(staging, ignore_errors=True)
    staging.mkdir(parents=True)
    for f in SHIPPED_FILES:
        shutil.copy2(run_dir / f, staging / f.replace("best_policy.", "policy."))
    final = read_json(run_dir / "final.json", MAX_DOCUMENT_BYTES)
    (staging / "card.md").write_text(model_card(config, run_dir, final, name))  # under the checkpoint's name
    size = (staging / "policy.safetensors").stat().st_size
    if size > 20e6:
        shutil.rmtree(staging)
        raise ValueError(f"the policy of {run_dir} is {size / 1e6:.1f} MB; shipped checkpoints stay under 20 MB")
    write_json(
        staging / "checkpoint.json",
        {
            "policy_class": read_json(staging / "policy.json", MAX_DOCUMENT_BYTES)["policy_class"],
            "steps": best["steps"],
            "env_id": config.env_id,
            "task": task_label(config.env_id, config.env_kwargs),
            "algo": config.algo,
            **acting,
        },
    )
    target = learned.CHECKPOINTS / name
    if target.exists():
        old = learned.CHECKPOINTS / f".{name}.old"
        shutil.rmtree(old, ignore_errors=True)
        os.replace(target, old)
        os.replace(staging, target)
        shutil.rmtree(old)
    else:
        os.replace(staging, target)
    return target


def attach_study(study_dir: Path, checkpoint: Path) -> Path:
    """Give shipped ``checkpoint`` the study in ``study_dir`` (seeds.json, seeds_profile.png) and rewrite its
    card; ``ValueError`` unless the study trained the checkpoint's config (its seed aside)."""
    study = read_json(study_dir / "study.json", MAX_DOCUMENT_BYTES)
    config = load_run(checkpoint)
    own = {k: v for k, v in dataclasses.asdict(config).items() if k != "seed"}
    differing = sorted(k for k in own.keys() | study["config"].keys() if own.get(k) != study["config"].get(k))
    if differing:
        raise ValueError(f"{study_dir} trained another config than {checkpoint.name}'s: {differing} differ")
    shutil.copyfile(study_dir / "study.json", checkpoint / "seeds.json")
    shutil.copyfile(study_dir / "profile.png", checkpoint / "seeds_profile.png")
    final = read_json(checkpoint / "final.json", MAX_DOCUMENT_BYTES)
    write_atomically(checkpoint / "card.md", model_card(config, checkpoint, final, checkpoint.name))
    return checkpoint
