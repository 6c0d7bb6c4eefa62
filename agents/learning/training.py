"""Training runs: a checked config, the envs and SB3 model it describes, periodic task-metric evaluation,
atomic checkpoints and resumable run folders.  ``train.py`` is the command line.

A run folder holds::

    config.yaml         the resolved config (defaults filled in, overrides applied)
    meta.json           seed, package versions, commit, machine
    tb/                 TensorBoard logs (SB3's, plus eval/* task metrics)
    evaluations.jsonl   one line per periodic evaluation: steps, wall seconds, task metrics with 95 % CIs
    curve.png           task success vs environment steps and vs wall time
    latest.zip          the latest checkpoint (model, optimiser) -- written via a temporary file + rename
    replay.pkl          the replay buffer at that checkpoint (off-policy algorithms), same way
    progress.json       steps done and wall seconds spent (summed over resumed sessions)
    final.json, card.md the final evaluation and the model card, when the run completes
"""

from __future__ import annotations

import gc
import json
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import gymnasium as gym

from panda_grasp_env.agents.evaluation.episodes import play_episode
from panda_grasp_env.agents.evaluation.metrics import aggregate, rate
from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec, task_label
from panda_grasp_env.agents.learning.config import (
    ALGORITHMS,
    DEMONSTRATION_ALGORITHMS,
    HEIGHTMAP_ALGORITHMS,
    SELECTION_SEED_OFFSET,
    TEST_SEED_OFFSET,
    TrainConfig,
    algo_arguments,
    check_buffer_bytes,
    load_class,
    load_run,
    make_env,
    make_vec_env,
    observation_transform,
    steps_label,
    training_env,
)
from panda_grasp_env.agents.learning.imitation import Demonstrations
from panda_grasp_env.agents.learning.policy_files import class_name
from panda_grasp_env.agents.learning.records import (
    earlier_tests,
    load_best_policy,
    model_card,
    plot_curve,
    read_evaluations,
    save_best_policy,
    write_best_record,
)
from panda_grasp_env.agents.policies.learned import Checkpoint
from panda_grasp_env.agents.policies.policy_agent import PolicyAgent
from panda_grasp_env.tooling.runs import (
    atomic_path,
    check_run_files,
    commit,
    new_run_folder,
    read_progress,
    run_key,
    sign_run_files,
    write_atomically,
    write_json,
)


def build_model(config: TrainConfig, env: Any, log_dir: Path | None) -> Any:
    """A fresh SB3 model for ``config`` on the vectorised ``env``, logging to TensorBoard under ``log_dir``.

    The heightmap policy learns the env's primitives, rotations and cell size from the env itself.
    """
    algo_path, policy = ALGORITHMS[config.algo]
    algo_class = load_class(algo_path)
    policy_kwargs = dict(config.policy_kwargs)
    kwargs = algo_arguments(config)
    if config.algo in HEIGHTMAP_ALGORITHMS:
        policy = load_class(policy)
        probe = make_env(config)
        policy_kwargs = {
            "primitives": probe.unwrapped.task.primitives,
            "rotations": probe.unwrapped.actions.rotations,
            "cell_size": probe.unwrapped.actions.grid.resolution,
            "command": "command" in getattr(probe.observation_space, "spaces", {}),
            "goal": "goal_heightmap" in getattr(probe.observation_space, "spaces", {}),
            **policy_kwargs,
        }
        probe.close()
    elif not isinstance(env.observation_space, gym.spaces.Dict):
        policy = "MlpPolicy"
    check_buffer_bytes(config, algo_class, env, kwargs)
    if config.her is not None:
        from stable_baselines3 import HerReplayBuffer

        kwargs["replay_buffer_class"] = HerReplayBuffer
        kwargs["replay_buffer_kwargs"] = dict(config.her)
    try:
        return algo_class(
            policy,
            env,
            seed=config.seed,
            policy_kwargs=policy_kwargs,
            tensorboard_log=str(log_dir) if log_dir is not None else None,
            verbose=0,
            **kwargs,
        )
    except TypeError as error:
        raise ValueError(f"{config.algo}: bad algo_kwargs/policy_kwargs/her: {error}") from None


def initial_policy_source(config: TrainConfig) -> Any:
    """The checkpoint (``panda_grasp_env.agents.policies.learned.Checkpoint``) that ``config.init_policy`` names,
    checked against the run before anything is written: ``ValueError`` if it is unknown, was trained with another
    algorithm, or acts on other observation or action spaces than the run's training env."""
    name = config.init_policy
    try:
        source = Checkpoint(str(name))
    except ValueError as error:  # it lists the shipped checkpoints
        raise ValueError(f"init_policy: {error}") from None
    same_policy = {source.config.algo, config.algo} <= set(HEIGHTMAP_ALGORITHMS)  # one Q-policy, two learners
    if source.config.algo != config.algo and not same_policy:
        raise ValueError(f"init_policy {name} was trained with {source.config.algo}, this run uses {config.algo}")
    policy = source.load_policy()
    env = training_env(config)  # what the run's policy will see and do
    try:
        for what in ("observation_space", "action_space"):
            if getattr(policy, what) != getattr(env, what):
                raise ValueError(
                    f"init_policy {name}: its {what} {getattr(policy, what)} is not this run's {getattr(env, what)}"
                )
    finally:
        env.close()
    return source


def load_initial_policy(model: Any, config: TrainConfig, source: Any) -> None:
    """Copy the policy weights of ``source`` (checked by ``initial_policy_source``) into the fresh ``model``;
    ``ValueError`` if its network differs from the run's (other ``policy_kwargs``)."""
    try:
        model.policy.load_state_dict(source.load_policy().state_dict())
    except RuntimeError as error:  # another net_arch: missing keys or tensors of other shapes
        raise ValueError(
            f"init_policy {config.init_policy}: its network does not match this run's policy_kwargs "
            f"{config.policy_kwargs} (it was trained with {source.config.policy_kwargs}): "
            f"{error}"
        ) from None


# --- evaluation ---------------------------------------------------------------------------


def evaluate_policy(
    model: Any,
    config: TrainConfig,
    episodes: int,
    env: gym.Env | None = None,
    first_seed: int | None = None,
    acting: Mapping[str, bool] | None = None,
) -> dict[str, Any]:
    """Task metrics (``panda_grasp_env.agents.evaluation.metrics.aggregate``) of ``model`` (an SB3 model or policy) acting as a
    ``PolicyAgent`` over ``episodes`` episodes seeded ``first_seed``, ``first_seed + 1``, ... (default: the
    validation seeds, ``eval_seed``...), acting by the rules ``acting`` turns on (``PolicyAgent``'s
    ``ACTING_RULES``; none by default)."""
    import torch

    torch.set_num_threads(config.torch_threads)  # as in training: other thread counts may round (and choose) apart
    first_seed = config.eval_seed if first_seed is None else first_seed
    own_env = env is None
    env = make_env(config) if env is None else env
    agent = PolicyAgent(model, observation_transform(config), config.name, **(acting or {}))
    task = task_label(config.env_id, config.env_kwargs)
    results = [
        play_episode(env, agent, EpisodeSpec(config.name, task, first_seed + i))["result"] for i in range(episodes)
    ]
    if own_env:
        env.close()
    metrics = next(iter(aggregate(results).values()))
    tiers = sorted({result["tier"] for result in results if "tier" in result})
    if tiers:  # a structure task: its learning curve per tier
        by_tier = {tier: [result["success"] for result in results if result.get("tier") == tier] for tier in tiers}
        metrics["trial_success_by_tier"] = {str(tier): rate(sum(won), len(won)) for tier, won in by_tier.items()}
    return metrics


def headline(metrics: dict[str, Any]) -> dict[str, float]:
    """The few numbers a learning curve follows."""
    return {
        "success": metrics["trial_success"]["rate"],
        "completion": metrics["completion"]["rate"],
        "grasp_success": metrics["grasp_success"]["rate"],
        "action_efficiency": metrics["action_efficiency"],
    }


# --- the run -----------------------------------------------------------------------------------


#: The metrics ``validation_score`` ranks by.
SCORE_KEYS = ("trial_success", "action_efficiency", "grasp_success")


def evaluate_on_selection_seeds(policy: Any, config: TrainConfig, episodes: int) -> dict[str, Any]:
    """``evaluate_policy`` on ``episodes`` selection seeds (``eval_seed + SELECTION_SEED_OFFSET`` ...): for
    choosing between policies or runs without touching the validation or the test seeds."""
    return evaluate_policy(policy, config, episodes, first_seed=config.eval_seed + SELECTION_SEED_OFFSET)


def validation_score(metrics: dict[str, Any]) -> tuple[float, ...]:
    """How checkpoints are ranked on the validation episodes: success, then efficiency, then grasp success."""
    success, efficiency, grasps = (metrics[key] for key in SCORE_KEYS)
    return (success["rate"], efficiency, grasps["rate"])


def save_checkpoint(model: Any, run_dir: Path, wall_seconds: float) -> None:
    """latest.zip (+ replay.pkl), signed (``runs.sign_run_files``: SB3 writes both as pickles), and
    progress.json, each through a temporary file and a rename."""
    with atomic_path(run_dir / "latest.zip") as tmp:
        model.save(tmp)
    written = ["latest.zip"]
    if getattr(model, "replay_buffer", None) is not None:
        with atomic_path(run_dir / "replay.pkl") as tmp:
            model.save_replay_buffer(tmp)
        written.append("replay.pkl")
    sign_run_files(run_dir, written)
    write_json(run_dir / "progress.json", {"steps": int(model.num_timesteps), "wall_seconds": round(wall_seconds, 1)})


def _callback(config: TrainConfig, run_dir: Path, wall_before: float, progress_bar: bool) -> Any:
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class RunCallback(BaseCallback):
        """Evaluation with the task's metrics, checkpoints, the progress bar and the wall-time limit."""

        def _on_training_start(self) -> None:
            self.started = time.perf_counter()
            self.next_eval = (self.num_timesteps // config.eval_every + 1) * config.eval_every
            self.next_checkpoint = (self.num_timesteps // config.checkpoint_every + 1) * config.checkpoint_every
            self.eval_env = make_env(config)
            self.latest = ""
            evaluations = read_evaluations(run_dir)
            if evaluations:
                last = headline(evaluations[-1]["metrics"])
                self.latest = f"{last['success']:.2f}"
            if not evaluations:  # the curve starts from the untrained policy
                self.evaluate()
            self.bar = tqdm(
                total=config.total_steps,
                initial=self.num_timesteps,
                unit="step",
                disable=not progress_bar,
                dynamic_ncols=True,
                desc=config.name,
                mininterval=5.0,
            )

        def wall(self) -> float:
            return wall_before + time.perf_counter() - self.started

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            if self.num_timesteps >= self.next_eval:
                self.next_eval += config.eval_every
                self.evaluate()
            if self.num_timesteps >= self.next_checkpoint:
                self.next_checkpoint += config.checkpoint_every
                save_checkpoint(self.model, run_dir, self.wall())
            self.bar.set_postfix_str(f"eval success {self.latest or '-'}", refresh=False)  # tqdm shows the speed
            return config.max_minutes is None or self.wall() < 60 * config.max_minutes

        def evaluate(self) -> None:
            began = time.perf_counter()
            metrics = evaluate_policy(self.model, config, config.eval_episodes, self.eval_env)
            row = {
                "steps": int(self.num_timesteps),
                "wall_seconds": round(self.wall(), 1),
                "eval_seconds": round(time.perf_counter() - began, 1),
                "metrics": metrics,
            }
            with open(run_dir / "evaluations.jsonl", "a") as log:
                log.write(json.dumps(row, sort_keys=True) + "\n")
                log.flush()
                os.fsync(log.fileno())
            for key, value in headline(metrics).items():
                self.logger.record(f"eval/{key}", value)
            self.logger.dump(self.num_timesteps)
            self.latest = f"{metrics['trial_success']['rate']:.2f}"
            plot_curve(run_dir, f"{config.name}: {config.algo} on {config.env_id}", steps_label(config))
            if validation_score(metrics) > max(
                (validation_score(r["metrics"]) for r in read_evaluations(run_dir)[:-1]), default=(-1.0,)
            ):
                save_best_policy(self.model.policy, run_dir, int(self.num_timesteps))

        def _on_training_end(self) -> None:
            self.bar.close()
            self.eval_env.close()

    return RunCallback()


def start_run(config: TrainConfig, runs_dir: Path) -> Path:
    """A fresh run folder ``runs_dir/<name>-seed<seed>[-N]`` with config.yaml and meta.json (which, for a run
    that starts from ``init_policy``, records the checkpoint's folder, step and policy.zip digest); ``ValueError``
    before anything is written if that checkpoint does not fit the run, or if its demonstrations' dataset is
    missing or refused (``imitation.Demonstrations.data_folder``)."""
    if config.algo in DEMONSTRATION_ALGORITHMS:
        Demonstrations.of(config.algo_kwargs["demonstrations"]).data_folder()
    if config.init_policy is None:
        return new_run_folder(runs_dir, config)
    return new_run_folder(runs_dir, config, init_policy=initial_policy_source(config).provenance())


def train(
    config: TrainConfig, run_dir: Path, resume: bool = False, progress_bar: bool = True, trust: bool = False
) -> dict[str, Any]:
    """Train (or continue) the run in ``run_dir`` to ``config.total_steps`` or until ``max_minutes`` of wall time
    are spent, then evaluate it (``finish``); Ctrl-C checkpoints and re-raises.

    A resumed run loads latest.zip and replay.pkl (SB3 pickles) only if this user's job signed them in this
    folder (``runs.check_run_files``), or with ``trust=True``.  The run's model is freed before this returns:
    SB3's model sits in reference cycles (its callbacks and logger point back at it), which Python's collector
    frees only at its next pass, so a process training one run after another (``train.py --seeds``, the tests)
    grew by ~230 MB a run."""
    try:
        return _train(config, run_dir, resume, progress_bar, trust)
    finally:
        gc.collect()  # the finished run's model, unreachable now that _train has returned


def _train(config: TrainConfig, run_dir: Path, resume: bool, progress_bar: bool, trust: bool) -> dict[str, Any]:
    import torch

    torch.set_num_threads(config.torch_threads)
    run_key()  # the key that signs its checkpoints: one others could know stops the run now, not at its first save
    progress = read_progress(run_dir / "progress.json") if resume else {"steps": 0, "wall_seconds": 0.0}
    budget_left = config.max_minutes is None or progress["wall_seconds"] < 60 * config.max_minutes
    will_learn = progress["steps"] < config.total_steps and budget_left
    source = initial_policy_source(config) if config.init_policy is not None and not resume else None
    env = make_vec_env(config)
    try:
        if resume:
            replay = will_learn and (run_dir / "replay.pkl").exists()  # not for a finished run resumed to re-test
            if not trust:
                check_run_files(run_dir, ["latest.zip"] + (["replay.pkl"] if replay else []))
            algo_path, policy = ALGORITHMS[config.algo]
            # The config's algo_kwargs replace the saved ones (a resumed run may change them: RESUME_CHANGEABLE).
            # The policy class comes from the config, not the pickle: a checkpoint written before a module moved
            # names one (``agents.heightmap_policy``, ``panda_grasp_env.agents.heightmap_policy``) that no longer
            # exists, or that policy files may not name.
            custom_objects = {"policy_class": load_class(policy)} if config.algo in HEIGHTMAP_ALGORITHMS else None
            try:
                model = load_class(algo_path).load(
                    run_dir / "latest.zip",
                    env=env,
                    tensorboard_log=str(run_dir / "tb"),
                    custom_objects=custom_objects,
                    **algo_arguments(config),
                )
                if replay:
                    model.load_replay_buffer(run_dir / "replay.pkl")
            except Exception as error:  # a truncated checkpoint: say which files, do not train on
                raise ValueError(f"cannot resume {run_dir} from latest.zip / replay.pkl: {error}") from error
        else:
            model = build_model(config, env, run_dir / "tb")
            if source is not None:
                load_initial_policy(model, config, source)
        callback = _callback(config, run_dir, float(progress["wall_seconds"]), progress_bar)
        if will_learn:
            try:
                model.learn(
                    config.total_steps - int(model.num_timesteps),
                    callback=callback,
                    reset_num_timesteps=not resume,
                    tb_log_name="run",
                )
            except KeyboardInterrupt:
                if hasattr(callback, "started"):  # not while SB3 set up (resetting the envs): nothing learned yet
                    save_checkpoint(model, run_dir, callback.wall())
                raise
    finally:
        env.close()
    wall = callback.wall() if hasattr(callback, "started") else float(progress["wall_seconds"])
    save_checkpoint(model, run_dir, wall)
    # A run ends at total_steps or when its time budget (max_minutes) is spent; both are final.
    return finish(model, config, run_dir, wall)


def stopped_by(config: TrainConfig, steps: int, wall_seconds: float) -> str:
    """Why training ended: ``total_steps``, ``max_minutes`` or ``interrupted`` (Ctrl-C / SIGTERM, then finished)."""
    if steps >= config.total_steps:
        return "total_steps"
    if config.max_minutes is not None and wall_seconds >= 60 * config.max_minutes:
        return "max_minutes"
    return "interrupted"


def finish(model: Any, config: TrainConfig, run_dir: Path, wall_seconds: float) -> dict[str, Any]:
    """The final test of the best validated policy (``final_test``) once training has ended; with
    ``selection_episodes``, of the better of that one and the final policy (``select_on_selection_seeds``)."""
    steps = int(model.num_timesteps)
    if not (run_dir / "best.json").exists():  # no periodic evaluation ran: the final policy is the best known
        save_best_policy(model.policy, run_dir, steps, chosen_by="final")
    elif config.selection_episodes:
        select_on_selection_seeds(model.policy, config, run_dir, steps)
    return final_test(config, run_dir, steps, wall_seconds)


def select_on_selection_seeds(final_policy: Any, config: TrainConfig, run_dir: Path, steps: int) -> None:
    """Play the validated best and the final policy (step ``steps``) for ``config.selection_episodes`` episodes
    each on the selection seeds; the final one becomes the best (``chosen_by="selection"``) if it ranks higher
    (``validation_score``; a tie keeps the validated one).  best.json records both figures.

    Periodic validations are few episodes each and the best of many of them flatters its policy; the final
    policy, never picked by them, is the natural rival."""
    best_policy, best = load_best_policy(run_dir)
    if best["steps"] == steps:  # the final policy is the validated best
        return
    first = config.eval_seed + SELECTION_SEED_OFFSET
    figures = {}
    for role, policy, at in (("validated_best", best_policy, best["steps"]), ("final", final_policy, steps)):
        metrics = evaluate_on_selection_seeds(policy, config, config.selection_episodes)
        figures[role] = {"steps": at, **{key: metrics[key] for key in SCORE_KEYS}}
    selection = {
        "episodes": config.selection_episodes,
        "seeds": [first, first + config.selection_episodes - 1],
        **figures,
    }
    if validation_score(figures["final"]) > validation_score(figures["validated_best"]):
        save_best_policy(final_policy, run_dir, steps, chosen_by="selection", selection=selection)
    else:
        write_best_record(run_dir, best["steps"], best["chosen_by"], selection)  # its weights stay as saved


def retest(run_dir: Path) -> dict[str, Any]:
    """``final_test`` again on a run whose training has ended, or on a shipped checkpoint folder (after the
    evaluation protocol or the physics changed)."""
    config = load_run(run_dir)
    # A run's totals are in progress.json; a shipped checkpoint keeps its run's in final.json.
    totals = run_dir / ("progress.json" if (run_dir / "progress.json").is_file() else "final.json")
    if not (run_dir / "best.json").is_file() or not totals.is_file():
        raise ValueError(f"{run_dir} has no best policy to test yet (best.json, {totals.name})")
    progress = read_progress(totals)
    # A shipped checkpoint is tested as it acts when shipped (by its acting rules, if it has any).
    acting = Checkpoint(run_dir).acting if (run_dir / "checkpoint.json").is_file() else None
    return final_test(config, run_dir, int(progress["steps"]), float(progress["wall_seconds"]), acting)


def final_test(
    config: TrainConfig, run_dir: Path, steps: int, wall_seconds: float, acting: Mapping[str, bool] | None = None
) -> dict[str, Any]:
    """Test the best validated policy on held-out seeds (``final_eval_episodes`` episodes from
    ``eval_seed + TEST_SEED_OFFSET``): final.json and card.md.  ``acting``: the rules it acts by (a
    shipped checkpoint's ``Checkpoint.acting``); final.json names those on."""
    policy, best = load_best_policy(run_dir)
    began = time.perf_counter()
    metrics = evaluate_policy(
        policy,
        config,
        config.final_eval_episodes,
        first_seed=config.eval_seed + TEST_SEED_OFFSET,
        acting=acting,
    )
    evaluations = read_evaluations(run_dir)
    first_90 = next((r for r in evaluations if r["metrics"]["trial_success"]["rate"] >= 0.9), None)
    final = {
        "steps": steps,
        "best_steps": best["steps"],
        "chosen_by": best.get("chosen_by", "validation"),
        **({"selection": best["selection"]} if "selection" in best else {}),
        "policy_class": class_name(type(policy)),
        "test_seeds": [
            config.eval_seed + TEST_SEED_OFFSET,
            config.eval_seed + TEST_SEED_OFFSET + config.final_eval_episodes - 1,
        ],
        "stopped_by": stopped_by(config, steps, wall_seconds),
        "wall_seconds": round(wall_seconds, 1),
        "steps_per_second": round(steps / max(wall_seconds, 1e-9), 2),
        "final_eval_seconds": round(time.perf_counter() - began, 1),
        "test_commit": commit(),  # a retest may run on newer code than the training did
        "steps_to_90_percent": first_90["steps"] if first_90 else None,
        "minutes_to_90_percent": round(first_90["wall_seconds"] / 60, 1) if first_90 else None,
        "metrics": metrics,
        **{rule: True for rule, on in (acting or {}).items() if on},
        "earlier": earlier_tests(run_dir, best["steps"], steps),
    }
    write_json(run_dir / "final.json", final)
    plot_curve(run_dir, f"{config.name}: {config.algo} on {config.env_id}", steps_label(config))
    shipped_as = run_dir.resolve().name if (run_dir / "checkpoint.json").is_file() else None
    write_atomically(run_dir / "card.md", model_card(config, run_dir, final, shipped_as))
    return final
