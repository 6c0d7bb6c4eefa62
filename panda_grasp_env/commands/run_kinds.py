"""The kinds of run ``train.py`` trains, each with the same steps, chosen by the kind a config declares.

A config declares its kind in its ``kind`` key: ``fall_dynamics`` for the falling-tower ConvLSTM
(``agents/learning/falls/``); a policy's config has none (``agents/learning/``).  A folder declares the kind
of what it holds in the same way: a run folder or a shipped checkpoint in its config.yaml, a study over
training seeds in the config its study.json records.  ``train.py`` reads the declared kind, looks it up in
``RUN_KINDS`` and runs its steps (``RunKind``); what a kind cannot do is a ``ValueError`` saying why.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from panda_grasp_env.agents.learning.config import check_policy_resume, config_from_dict, read_config
from panda_grasp_env.agents.learning.falls.config import check_fall_resume, fall_config
from panda_grasp_env.agents.learning.falls.records import ship_fall_run
from panda_grasp_env.agents.learning.falls.training import start_fall_run, test_fall_model, train_fall_model
from panda_grasp_env.agents.learning.records import ship
from panda_grasp_env.agents.learning.training import retest, start_run, train
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json, read_yaml


@dataclass(frozen=True)
class RunKind:
    """What ``train.py`` does with one kind of run, step by step."""

    #: The checked config of a mapping read from a source; ``ValueError`` naming the bad key.
    config: Callable[[dict[str, Any], str], Any]
    #: A fresh run folder for a config, under the folder that holds run folders.
    start: Callable[[Any, Path], Path]
    #: ``(saved, resumed)`` configs of a run: ``ValueError`` naming the keys a resumed run cannot change.
    check_resume: Callable[[Any, Any], None]
    #: The checkpoint in a run folder that a run resumes from.
    latest: str
    #: ``(config, run folder, resume, progress bar, trust)``: trains the run to its end, returns its outcome;
    #: Ctrl-C checkpoints it and re-raises.
    train: Callable[[Any, Path, bool, bool, bool], dict[str, Any]]
    #: Prints a finished run's outcome; the exit status.
    report: Callable[[dict[str, Any], Path], int]
    #: ``(finished run, checkpoint name, acting rules)``: the shipped checkpoint's folder.
    ship: Callable[[Path, str, Mapping[str, bool]], Path]
    #: ``(run or checkpoint folder, overrides)``: tests it again and prints the result; the exit status.
    retest: Callable[[Path, list[str]], int]
    #: ``(config, seeds, runs folder, workers, Ray address, progress bar)``: trains the config on each seed and
    #: prints the study; the exit status (``--seeds``).
    train_seeds: Callable[[Any, list[int], Path, int, str | None, bool], int]
    #: ``(study folder, checkpoint name)``: the shipped checkpoint the study is attached to.
    attach_study: Callable[[Path, str], Path]


# --- policies -------------------------------------------------------------------------------------


def train_policy(config: Any, run_dir: Path, resume: bool, progress: bool, trust: bool) -> dict[str, Any]:
    return train(config, run_dir, resume=resume, progress_bar=progress, trust=trust)


def report_policy(outcome: dict, run_dir: Path) -> int:
    if outcome["stopped_by"] == "max_minutes":
        print(
            f"time budget spent at {outcome['steps']} steps; more with  python train.py --resume {run_dir} max_minutes=M"
        )
    return print_policy_outcome(outcome, run_dir)


def print_policy_outcome(outcome: dict, run_dir: Path) -> int:
    print(json.dumps({k: v for k, v in outcome.items() if k != "metrics"}, indent=2))
    metrics = outcome["metrics"]
    grasps = metrics["grasp_success"]  # none attempted in low-level (ee_delta) or tower-break episodes
    print(
        f"final: success {metrics['trial_success']['rate']:.3f} {metrics['trial_success']['ci95']}, "
        + (f"grasp success {grasps['rate']:.3f}, " if grasps["n"] else "")
        + f"efficiency {metrics['action_efficiency']:.3f} (N={metrics['episodes']}); card: {run_dir / 'card.md'}"
    )
    return 0


def ship_policy(run_dir: Path, name: str, acting: Mapping[str, bool]) -> Path:
    return ship(run_dir, name, **acting)


def retest_policy(folder: Path, overrides: list[str]) -> int:
    if overrides:
        raise ValueError(f"--retest of a policy takes no overrides, got {overrides}")
    return print_policy_outcome(retest(folder), folder)


def train_policy_seeds(config: Any, seeds: list[int], runs: Path, workers: int, ray: str | None, progress: bool) -> int:
    """The config trained on each seed, then the study folder's aggregate printed."""
    from panda_grasp_env.agents.learning.seed_runs import train_seeds

    where = f"Ray tasks on {ray}" if ray else f"{workers} local process(es)"
    print(f"training {config.name} on seeds {seeds} in {where}; each run folder under {runs}")
    try:
        study = train_seeds(config, seeds, runs, workers, ray, progress)
    except KeyboardInterrupt:
        print("\ninterrupted: finished and checkpointed runs are kept; the same command continues", file=sys.stderr)
        return 130
    print((study / "study.md").read_text())
    print(f"study: {study} (attach to a shipped checkpoint: python train.py --ship {study} --name NAME)")
    return 0


def attach_policy_study(study: Path, name: str) -> Path:
    from panda_grasp_env.agents.learning.records import attach_study
    from panda_grasp_env.agents.policies.learned import CHECKPOINTS

    if not (CHECKPOINTS / name / "checkpoint.json").is_file():
        raise ValueError(f"no shipped checkpoint {name!r} to attach {study} to")
    return attach_study(study, CHECKPOINTS / name)


POLICY = RunKind(
    config=config_from_dict,
    start=start_run,
    check_resume=check_policy_resume,
    latest="latest.zip",
    train=train_policy,
    report=report_policy,
    ship=ship_policy,
    retest=retest_policy,
    train_seeds=train_policy_seeds,
    attach_study=attach_policy_study,
)


# --- fall dynamics --------------------------------------------------------------------------------


def print_fall_metrics(metrics: dict) -> None:
    for name, by_horizon in metrics.items():
        for horizon, m in by_horizon.items():
            print(
                f"{name:18s} {horizon}: mean block IoU {m['mean_block_iou']:.4f}, foreground accuracy "
                f"{m['foreground_accuracy']:.4f}, pixel accuracy {m['pixel_accuracy']:.4f} ({m['frames']} frames)"
            )


def print_fall_directions(direction: dict) -> None:
    """One line per predictor of ``fall_directions``' figures over all test towers."""
    print(
        f"fall direction: {direction['fell']} of {direction['sequences']} test towers fell, "
        f"{direction['hidden']} of them hidden in the first frame"
    )
    for name, d in direction["predictors"].items():
        if d["within_45"] is not None:
            print(
                f"{name:18s} within 45 degrees {d['within_45']:.3f}, median error {d['median_error_deg']:.1f} "
                f"degrees ({d['no_direction']} without a direction)"
            )


def report_fall(outcome: dict, run_dir: Path) -> int:
    if outcome["stopped_by"] == "max_minutes":
        print(f"time budget spent; more with  python train.py --resume {run_dir} max_minutes=M")
    print_fall_metrics(outcome["metrics"])
    print_fall_directions(outcome["direction"])
    print(f"card: {run_dir / 'card.md'}")
    return 0


def ship_fall(run_dir: Path, name: str, acting: Mapping[str, bool]) -> Path:
    if any(acting.values()):
        raise ValueError("a fall-dynamics model acts by no rules (the acting rules' flags)")
    return ship_fall_run(run_dir, name)


def retest_fall(folder: Path, overrides: list[str]) -> int:
    """``--retest`` of a fall model: its test split, or another recorded dataset's with ``dataset=PATH``."""
    unknown = [o for o in overrides if not o.startswith("dataset=")]
    if unknown or len(overrides) > 1:
        raise ValueError(f"--retest of a fall model takes at most dataset=PATH, got {overrides}")
    result = test_fall_model(folder, overrides[0].partition("=")[2] if overrides else None)
    print(f"test split of {result['dataset']}: {result['test_sequences']} sequences")
    print_fall_metrics(result["metrics"])
    print_fall_directions(result["direction"])
    print(f"results: {folder / 'retest.json'}")
    return 0


def no_fall_seeds(*args: Any) -> int:
    raise ValueError("--seeds trains policies; a fall-dynamics config has one dataset split, not seeds")


def no_fall_study(study: Path, name: str) -> Path:
    raise ValueError(f"{study} is a study of a fall-dynamics config: --seeds trains policies only")


FALL_DYNAMICS = RunKind(
    config=fall_config,
    start=start_fall_run,
    check_resume=check_fall_resume,
    latest="latest.pt",
    train=train_fall_model,
    report=report_fall,
    ship=ship_fall,
    retest=retest_fall,
    train_seeds=no_fall_seeds,
    attach_study=no_fall_study,
)

#: Every kind of run by the ``kind`` a config declares (a policy's declares none).
RUN_KINDS = {None: POLICY, "fall_dynamics": FALL_DYNAMICS}


# --- what a config or a folder declares -----------------------------------------------------------


def declared_kind(raw: Mapping[str, Any], source: str) -> RunKind:
    """The kind of run the config mapping ``raw`` (read from ``source``) declares in its ``kind`` key: a policy
    where it declares none; ``ValueError`` naming a kind no run has."""
    kind = raw.get("kind")
    if not isinstance(kind, str | None) or kind not in RUN_KINDS:
        declared = [name for name in RUN_KINDS if name is not None]
        raise ValueError(f"{source}: kind={kind!r} is no kind of run: one of {declared}, or none for a policy")
    return RUN_KINDS[kind]


def load_run_config(path: Path, overrides: list[str], source: str) -> tuple[Any, RunKind]:
    """(checked config, kind) of a YAML config with ``key=value`` overrides, of the kind it declares."""
    raw = read_config(path, overrides)
    kind = declared_kind(raw, source)
    return kind.config(raw, source), kind


def run_kind(folder: Path) -> RunKind:
    """The kind a run folder or shipped checkpoint declares in its config.yaml (read within bounds: it may be
    someone else's); ``ValueError`` if it has none."""
    path = folder / "config.yaml"
    if not path.is_file():
        raise ValueError(f"{folder} is not a run folder (no config.yaml)")
    raw = read_yaml(path, MAX_DOCUMENT_BYTES) or {}
    if not isinstance(raw, dict):
        raise ValueError(f"config {path} must be a mapping of keys to values")
    return declared_kind(raw, str(path))


def folder_kind(folder: Path) -> tuple[str, RunKind]:
    """What ``folder`` holds and the kind of run it declares: ``("run", kind)`` for a run folder or shipped
    checkpoint (``run_kind``), ``("study", kind)`` for a study over training seeds, whose study.json records the
    config it trained (the study has no config.yaml); ``ValueError`` if it is neither."""
    if (folder / "config.yaml").is_file():
        return "run", run_kind(folder)
    path = folder / "study.json"
    if not path.is_file():
        raise ValueError(f"{folder} is neither a run folder (no config.yaml) nor a study over seeds (no study.json)")
    study = read_json(path, MAX_DOCUMENT_BYTES)
    config = study.get("config") if isinstance(study, dict) else None
    if not isinstance(config, dict):
        raise ValueError(f"{path} records no config it trained: not a study over seeds")
    return "study", declared_kind(config, str(path))
