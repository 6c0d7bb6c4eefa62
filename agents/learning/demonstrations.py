"""Record any ``evaluate.py`` agent's episodes as a Minari dataset: the Farama format for offline RL and imitation.

    python -m panda_grasp_env.agents.learning.demonstrations --agent expert --task Stack --episodes 1000
        [--seed-start 0] [--task-options KEY=VALUE ...] [--infos is_success,...] [--workers 2]
        [--shard-size 100] [--out data/minari] [--name panda_grasp_env/stack-expert-v0] [--lossless]

One episode per seed, through the env ``evaluate.py`` gives that agent on that task: its options, then
``--task-options`` (``obs_mode=rgbd`` records images).  Minari keeps each episode's seed, so
``reset(seed=...)`` and the recorded actions replay it: the physics is deterministic (``replay`` checks it).
``--infos`` names the ``info`` keys kept at every step; they must be numbers or arrays present at reset and at
every step.  Images are JPEG-encoded by Minari unless ``--lossless``, which exact replays of image
observations need.

``--workers`` processes record shards of ``--shard-size`` episodes, each its own Minari dataset
(``<name without version>-shardNNNNN-v0``) with a manifest (agent, task, options, seeds, episode count and
the SHA-256 of every data file) that this user's key signs (``tooling.runs.sign_run_files``).  A rerun keeps
the shards whose signed manifest matches their files and this recording, and records the rest, so Ctrl-C
loses at most the shards in progress; a shard someone else put there is recorded again, never combined.
At the end the shards are combined into ``<name>``, and the episodes per second are printed.  Datasets live under ``--out`` (Minari's ``MINARI_DATASETS_PATH``):
``minari.load_dataset(name)`` reads them there.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import shutil
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
from panda_grasp_env.agents.evaluation.episodes import make_agent, make_env
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec, all_agents, skip_reason, task_options_from_pairs
from panda_grasp_env.agents.learning.datasets import open_dataset, recorded_env
from panda_grasp_env.tooling.reading import read_json
from panda_grasp_env.tooling.runs import commit, is_signed, sha256, sign_run_files, write_json

#: A shard's manifest, in its dataset folder.
MANIFEST = "manifest.json"


def kept_infos(keys: tuple[str, ...]) -> type:
    """A Minari step callback that keeps only the ``info`` entries ``keys`` (a class: Minari builds it)."""
    from minari import StepDataCallback

    class KeptInfos(StepDataCallback):
        def __call__(self, env: Any, obs: Any, info: dict[str, Any], **step: Any) -> dict[str, Any]:
            data = super().__call__(env, obs=obs, info=info, **step)
            missing = [k for k in keys if k not in info]
            if missing:
                raise ValueError(
                    f"--infos {missing} are not in this step's info (keep keys present at reset and "
                    f"at every step; this one has {sorted(info)})"
                )
            data["info"] = {k: np.asarray(info[k]) for k in keys}
            return data

    return KeptInfos


def shard_id(name: str, index: int) -> str:
    """The dataset id of shard ``index`` of dataset ``name`` (``namespace/dataset-vN``)."""
    stem, version = name.rsplit("-v", 1)
    return f"{stem}-shard{index:05d}-v{version}"


def record_shard(job: dict[str, Any]) -> int:
    """Record one shard (a worker's job); returns the episodes it holds."""
    import minari

    os.environ["MINARI_DATASETS_PATH"] = job["out"]
    first = EpisodeSpec(job["agent"], job["task"], job["seeds"][0], job["options"])
    env = make_env(first)
    collector = minari.DataCollector(
        env,
        step_data_callback=kept_infos(job["infos"]),
        record_infos=bool(job["infos"]),
        jpeg_encoding=not job["lossless"],
    )
    for seed in job["seeds"]:
        agent = make_agent(EpisodeSpec(job["agent"], job["task"], seed, job["options"]), env)
        observation, info = collector.reset(seed=seed)
        agent.reset(observation, info)
        while True:
            observation, _, terminated, truncated, info = collector.step(agent.act(observation, info))
            if terminated or truncated:
                break
    with warnings.catch_warnings():  # Minari asks every dataset for an author's e-mail; this project has none
        warnings.filterwarnings("ignore", message="`author_email` is set to None")
        dataset = collector.create_dataset(
            dataset_id=job["dataset_id"],
            eval_env=env.spec,
            algorithm_name=f"panda_grasp_env agent {job['agent']!r}",
            author="panda_grasp_env",
            code_permalink=f"panda_grasp_env commit {commit()}",  # the code that recorded it
            description=f"{job['agent']} on {job['task']}, seeds {job['seeds'][0]}-{job['seeds'][-1]}",
        )
    collector.close()
    folder = Path(job["out"]) / job["dataset_id"]
    write_json(folder / MANIFEST, manifest(job, folder, dataset.total_episodes))
    sign_run_files(folder, [MANIFEST])
    return dataset.total_episodes


def manifest(job: dict[str, Any], folder: Path, episodes: int) -> dict[str, Any]:
    """What a shard holds: the job that recorded it (agent, task, options, seeds, infos, image encoding), its
    episode count and the SHA-256 of each file under ``folder`` / data, as JSON values."""
    files = {str(p.relative_to(folder)): sha256(p) for p in sorted((folder / "data").rglob("*")) if p.is_file()}
    facts = {k: job[k] for k in ("agent", "task", "options", "seeds", "infos", "lossless")}
    return json.loads(json.dumps({**facts, "episodes": episodes, "files": files}))


def finished(job: dict[str, Any]) -> bool:
    """Whether the job's shard is recorded: its folder holds a manifest this user's key signed there, for this
    job, whose hashes match the files and whose episodes are all there.  Any other shard folder (cut short by
    Ctrl-C, recorded for other seeds, or put there by someone else) is removed, to be recorded again."""
    folder = Path(job["out"]) / job["dataset_id"]
    if not folder.exists():
        return False
    why = "its manifest is not one this user's job signed there"
    try:
        if is_signed(folder, MANIFEST):
            recorded = read_json(folder / MANIFEST, 64 << 20)
            expected = manifest(job, folder, len(job["seeds"]))
            why = "its manifest does not match its files and this recording"
            if recorded == expected and open_dataset(folder / "data").total_episodes == len(job["seeds"]):
                return True
    except ValueError as error:
        why = str(error)
    print(f"shard {job['dataset_id']} recorded again: {why}")
    shutil.rmtree(folder)
    return False


def record(args: argparse.Namespace) -> Any:
    """Record (or finish recording) the dataset; returns it."""
    import minari
    from minari.namespace import create_namespace, list_local_namespaces

    os.environ["MINARI_DATASETS_PATH"] = str(args.out.resolve())
    seeds = list(range(args.seed_start, args.seed_start + args.episodes))
    options = tuple(sorted(args.task_options.items()))
    jobs = [
        {
            "agent": args.agent,
            "task": args.task,
            "options": options,
            "seeds": seeds[i : i + args.shard_size],
            "infos": args.infos,
            "lossless": args.lossless,
            "out": str(args.out.resolve()),
            "dataset_id": shard_id(args.name, i // args.shard_size),
        }
        for i in range(0, len(seeds), args.shard_size)
    ]
    # The folder and the namespace exist before the workers start: two creating them at once collide.
    args.out.resolve().mkdir(parents=True, exist_ok=True)
    namespace = args.name.split("/")[0] if "/" in args.name else None
    if namespace is not None and namespace not in list_local_namespaces():
        create_namespace(namespace)
    todo = [job for job in jobs if not finished(job)]
    print(f"{len(jobs) - len(todo)} of {len(jobs)} shards already recorded; recording {len(todo)}")
    start, done = time.perf_counter(), 0
    if args.workers > 1 and len(todo) > 1:
        with multiprocessing.get_context("spawn").Pool(args.workers) as pool:
            for count in pool.imap_unordered(record_shard, todo):
                done += count
    else:
        for job in todo:
            done += record_shard(job)
    if done:
        print(
            f"recorded {done} episodes in {time.perf_counter() - start:.1f} s: "
            f"{done / (time.perf_counter() - start):.1f} episodes/s"
        )
    if (args.out.resolve() / args.name).exists():
        minari.delete_dataset(args.name)
    shards = [open_dataset(args.out.resolve() / job["dataset_id"] / "data") for job in jobs]
    dataset = minari.combine_datasets(shards, args.name)
    # Combining keeps the episodes but not their seeds, which replaying needs: put them back, in order.
    dataset.storage.update_episode_metadata([{"seed": seed} for seed in seeds])
    print(f"dataset {args.name}: {dataset.total_episodes} episodes, {dataset.total_steps} steps, under {args.out}")
    return dataset


def replay(dataset: Any, episode: int = 0) -> bool:
    """Whether resetting the dataset's env with an episode's seed and stepping its actions reproduces its
    observations (exactly for state; images only when recorded losslessly).  The env is this project's own
    registration of the id the dataset records (``datasets.recorded_env``), never the entry point it names."""
    data = next(dataset.iterate_episodes([episode]))
    seed = next(iter(dataset.storage.get_episode_metadata([episode])))["seed"]
    env = recorded_env(dataset)
    observation, _ = env.reset(seed=int(seed))
    same = [_equal(observation, data.observations, 0)]
    actions = data.actions
    for t in range(len(data.rewards)):
        action = {k: v[t] for k, v in actions.items()} if isinstance(actions, dict) else actions[t]
        observation, *_ = env.step(action)
        same.append(_equal(observation, data.observations, t + 1))
    env.close()
    return all(same)


def _equal(observation: Any, recorded: Any, t: int) -> bool:
    if isinstance(observation, dict):
        return all(np.array_equal(observation[k], recorded[k][t]) for k in observation)
    return bool(np.array_equal(observation, recorded[t]))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m panda_grasp_env.agents.learning.demonstrations",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--agent", required=True, help=f"one of {list(all_agents())}")
    parser.add_argument("--task", required=True, help=f"one of {list(BENCHMARKS)}")
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seed-start", type=int, default=0)
    parser.add_argument("--task-options", nargs="*", default=[], metavar="KEY=VALUE")
    parser.add_argument("--infos", default="is_success", help="comma-separated info keys kept per step ('' none)")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--shard-size", type=int, default=100)
    parser.add_argument("--out", type=Path, default=Path("data/minari"))
    parser.add_argument("--name", default=None, help="dataset id (default panda_grasp_env/<task>-<agent>-v0)")
    parser.add_argument("--lossless", action="store_true", help="store images raw, not JPEG-encoded")
    args = parser.parse_args(argv)
    if args.agent not in all_agents():
        parser.error(f"--agent {args.agent!r}: one of {list(all_agents())}")
    if args.task not in BENCHMARKS:
        parser.error(f"--task {args.task!r}: one of {list(BENCHMARKS)}")
    if (reason := skip_reason(args.agent, args.task)) is not None:
        parser.error(f"--agent {args.agent} does not play {args.task}: {reason}")
    for name in ("episodes", "workers", "shard_size"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    try:
        args.task_options = task_options_from_pairs(args.task_options, [args.task])
    except ValueError as error:
        parser.error(str(error))
    args.infos = tuple(key for key in args.infos.split(",") if key)
    args.name = args.name or f"panda_grasp_env/{args.task.lower()}-{args.agent.replace('_', '-')}-v0"
    if not args.name.rsplit("-v", 1)[-1].isdigit():
        parser.error(f"--name {args.name!r} must end in -v<version> (Minari's dataset ids)")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    dataset = record(args)
    print(f"replay of episode 0 reproduces it: {replay(dataset)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
