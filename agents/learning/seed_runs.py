"""One config trained on several seeds, and its figures over them: ``train.py --config C --seeds 0,1,2``.

Each seed is an ordinary run folder (``runs/<name>-seed<s>``, ``agents/learning/training.py``), trained in its own
local process (``--workers``) or as a Ray task (``--ray ADDRESS``, the engine ``evaluate.py --ray`` uses: a
task needs the package installed where it runs, and writes its run folder there; the driver keeps what
the aggregate needs).  A seed whose run folder already holds a finished run of the same config is not
trained again, and one interrupted is resumed, so a study stopped by Ctrl-C continues where it stood.

The runs' held-out test figures (``final.json``) are aggregated with ``rliable`` (Agarwal et al. 2021):
interquartile mean, mean and optimality gap with 95 % stratified-bootstrap intervals, and the
performance profile (the fraction of runs scoring above each threshold tau, with its bootstrap band).  A
study folder ``runs/<name>-seeds-<s1>-<s2>-...`` holds study.json, study.md and profile.png;
``train.py --ship STUDY --name N`` attaches it to shipped checkpoint N (same config but the seed) as
seeds.json and seeds_profile.png, and the model card and evaluate.py's report.html show it.
"""

from __future__ import annotations

import dataclasses
import multiprocessing
from pathlib import Path
from typing import Any

import yaml

from panda_grasp_env.agents.learning.config import TrainConfig, config_from_dict
from panda_grasp_env.agents.learning.seed_figures import profile_figure, score, study_markdown, study_summary
from panda_grasp_env.tooling.reading import MAX_DOCUMENT_BYTES, read_json, read_text
from panda_grasp_env.tooling.runs import ray_tasks, write_atomically, write_json


def parse_seeds(text: str) -> list[int]:
    """``--seeds 0,1,2`` as distinct non-negative ints; ``ValueError`` naming the culprit."""
    try:
        seeds = [int(s) for s in text.split(",") if s.strip()]
    except ValueError:
        raise ValueError(f"--seeds must be comma-separated integers, got {text!r}") from None
    if len(seeds) < 2 or min(seeds) < 0 or len(set(seeds)) < len(seeds):
        raise ValueError(f"--seeds needs two or more distinct seeds >= 0, got {text!r}")
    return seeds


def _config_text(config: TrainConfig) -> str:
    return yaml.safe_dump(dataclasses.asdict(config), sort_keys=False)


def train_seed(raw: dict[str, Any], runs_dir: str) -> dict[str, Any]:
    """Train the config ``raw`` (one seed's) to its end under ``runs_dir``: a finished run of the same config
    found there is kept, an unfinished one resumed, else a new run started.  Returns the seed, the run folder
    and its final.json (what the study needs, also from a Ray task on another machine)."""
    from panda_grasp_env.agents.learning.training import start_run, train
    from panda_grasp_env.tooling.runs import record_resume

    config = config_from_dict(raw, f"{raw['name']} seed {raw['seed']}")
    runs = Path(runs_dir)
    same = [
        d
        for d in sorted(runs.glob(f"{config.name}-seed{config.seed}*"))
        if (d / "config.yaml").is_file() and read_text(d / "config.yaml", MAX_DOCUMENT_BYTES) == _config_text(config)
    ]
    finished = [d for d in same if (d / "final.json").is_file()]
    resumable = [d for d in same if (d / "latest.zip").is_file() and not (d / "final.json").is_file()]
    if finished:
        run_dir = finished[0]
    elif resumable:
        run_dir = resumable[0]
        record_resume(run_dir, [])
        train(config, run_dir, resume=True, progress_bar=False)
    else:
        run_dir = start_run(config, runs)
        train(config, run_dir, progress_bar=False)
    final = read_json(run_dir / "final.json", MAX_DOCUMENT_BYTES)
    return {"seed": config.seed, "run_dir": str(run_dir), "final": final}


def _train_seed(arguments: tuple[dict[str, Any], str]) -> dict[str, Any]:
    return train_seed(*arguments)


def train_seeds(
    config: TrainConfig,
    seeds: list[int],
    runs_dir: Path,
    workers: int = 1,
    ray_address: str | None = None,
    progress_bar: bool = True,
) -> Path:
    """Train ``config`` on each of ``seeds`` (``workers`` local processes, or Ray tasks on ``ray_address``),
    then write the study folder (``write_study``); returns it.  The progress bar counts finished runs."""
    from tqdm import tqdm

    runs_dir = runs_dir.resolve()
    runs_dir.mkdir(parents=True, exist_ok=True)
    jobs = [(dataclasses.asdict(dataclasses.replace(config, seed=s)), str(runs_dir)) for s in seeds]
    pool = None
    if ray_address is not None:
        finished = ray_tasks(train_seed, jobs, ray_address)
    elif workers == 1:
        finished = map(_train_seed, jobs)
    else:
        pool = multiprocessing.get_context("spawn").Pool(workers)
        finished = pool.imap_unordered(_train_seed, jobs)
    outcomes = []
    bar = tqdm(total=len(seeds), desc=f"{config.name} seeds", unit="run", disable=not progress_bar)
    try:
        for outcome in finished:
            outcomes.append(outcome)
            bar.update(1)
            bar.set_postfix_str(f"seed {outcome['seed']}: test success {score(outcome['final'], 'trial_success'):.2f}")
    finally:
        bar.close()
        if pool is not None:
            pool.terminate()  # after Ctrl-C the workers have checkpointed their runs
            pool.join()
    return write_study(config, sorted(outcomes, key=lambda o: o["seed"]), runs_dir)


def study_folder(runs_dir: Path, config: TrainConfig, seeds: list[int]) -> Path:
    return runs_dir / f"{config.name}-seeds-{'-'.join(map(str, seeds))}"


def write_study(config: TrainConfig, outcomes: list[dict[str, Any]], runs_dir: Path) -> Path:
    """study.json, study.md and profile.png in the study folder; returns it."""
    study = study_summary(config, outcomes)
    folder = study_folder(runs_dir, config, study["seeds"])
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "study.json", study)
    write_atomically(folder / "study.md", f"# {config.name} over training seeds\n\n" + study_markdown(study) + "\n")
    import matplotlib.pyplot as plt

    figure = profile_figure(study)
    figure.savefig(folder / "profile.png", dpi=100)
    plt.close(figure)
    return folder
