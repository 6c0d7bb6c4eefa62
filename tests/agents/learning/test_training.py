"""Training runs (``agents/learning/training.py``, through ``train.py``): run folders, resume, retest,
selection, fine-tuning and validation seeds."""

import dataclasses
import json
import shutil

import numpy as np
import pytest
import torch as th
from testkit import CONFIGS, TINY_DQN

from panda_grasp_env.agents.learning.config import TrainConfig, load_config, make_vec_env
from panda_grasp_env.agents.learning.heightmap_policy import (
    HeightmapDQN,
    HeightmapQPolicy,
)
from panda_grasp_env.agents.learning.policy_files import load_policy
from panda_grasp_env.agents.learning.records import load_best_policy, save_best_policy, ship
from panda_grasp_env.agents.learning.training import validation_score
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.commands import run_kinds, train


def test_a_run_folder_holds_everything_and_resumes(finished_run):
    run = finished_run
    for name in ("config.yaml", "meta.json", "latest.zip", "replay.pkl", "curve.png", "final.json", "card.md"):
        assert (run / name).is_file(), name
    assert any((run / "tb").rglob("events.out.tfevents.*"))
    assert json.loads((run / "progress.json").read_text())["steps"] == 12
    evaluations = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    assert [e["steps"] for e in evaluations] == [0, 6, 12]  # untrained, then one per session, none repeated
    meta = json.loads((run / "meta.json").read_text())
    assert meta["seed"] == 0 and "torch" in meta["versions"]
    final = json.loads((run / "final.json").read_text())
    assert final["test_seeds"][0] == final["metrics"]["seeds"][0] == 1_000_000 + 100_000  # held out from validation
    assert final["best_steps"] in (0, 6, 12) and (run / "best_policy.safetensors").is_file()
    card = (run / "card.md").read_text()
    assert "95 % CI" in card and "environment steps | 12" in card
    assert not list(run.glob("*.tmp"))


def test_selection_episodes_pit_the_validated_best_against_the_final_policy_before_the_test(finished_run, tmp_path):
    run = tmp_path / finished_run.name
    shutil.copytree(finished_run, run)
    policy, _ = load_best_policy(run)
    save_best_policy(policy, run, 6)  # a validated best that is not the final policy (step 12)
    assert train.main(["--resume", str(run), "selection_episodes=2", "--trust", "--no-progress"]) == 0  # a copied run
    best = json.loads((run / "best.json").read_text())
    selection = best["selection"]
    assert selection["episodes"] == 2 and selection["seeds"] == [1_001_000, 1_001_001]  # clear of validation and test
    assert (selection["validated_best"]["steps"], selection["final"]["steps"]) == (6, 12)
    final_won = validation_score(selection["final"]) > validation_score(selection["validated_best"])
    assert (best["steps"], best["chosen_by"]) == ((12, "selection") if final_won else (6, "validation"))
    final = json.loads((run / "final.json").read_text())
    assert final["best_steps"] == best["steps"] and final["selection"] == selection
    assert "Before the test, on 2 selection episodes (seeds 1001000-1001001)" in (run / "card.md").read_text()


def test_init_policy_starts_a_run_from_a_checkpoints_weights(finished_run, tmp_path, monkeypatch):
    from panda_grasp_env.agents.learning.config import make_vec_env
    from panda_grasp_env.agents.learning.training import build_model, initial_policy_source, load_initial_policy

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    ship(finished_run, "tiny")
    source = learned.Checkpoint("tiny").load_policy().state_dict()
    config = load_config(CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny"])
    env = make_vec_env(config)
    model = build_model(config, env, None)
    assert not all(th.equal(v, model.policy.state_dict()[k]) for k, v in source.items())  # random to begin with
    load_initial_policy(model, config, initial_policy_source(config))
    assert all(th.equal(v, model.policy.state_dict()[k]) for k, v in source.items())
    narrower = load_config(
        CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny", "policy_kwargs.width=16"]
    )
    with pytest.raises(ValueError, match="init_policy tiny: its network does not match"):
        load_initial_policy(build_model(narrower, env, None), narrower, initial_policy_source(narrower))
    env.close()
    with pytest.raises(ValueError, match="init_policy tiny was trained with heightmap_dqn, this run uses sac"):
        initial_policy_source(dataclasses.replace(config, algo="sac", algo_kwargs={}))
    # The same Q-policy learned from demonstrations may start from it.
    demos = {**config.algo_kwargs, "demonstrations": {"dataset": "panda_grasp_env/any-v0", "episodes": 1}}
    assert initial_policy_source(dataclasses.replace(config, algo="heightmap_dqn_demos", algo_kwargs=demos))
    with pytest.raises(ValueError, match="init_policy tiny: its action_space"):
        initial_policy_source(
            load_config(CONFIGS / "grasp_clutter_dqn.yaml", [*TINY_DQN, "init_policy=tiny", "env_kwargs.rotations=8"])
        )

    # Through train.py: a fine-tuning run starts from the checkpoint's weights (with learning_starts above
    # total_steps nothing is learned, so its policy is the checkpoint's) and records where they came from.
    runs = tmp_path / "runs"
    cli = ["--config", str(CONFIGS / "grasp_clutter_dqn.yaml"), "--runs", str(runs), "--no-progress", *TINY_DQN]
    assert train.main([*cli, "init_policy=tiny", "total_steps=6", "algo_kwargs.learning_starts=100"]) == 0
    run = runs / "grasp_clutter_dqn-seed0"
    trained = load_policy(run / "best_policy")
    assert all(th.equal(v, trained.state_dict()[k]) for k, v in source.items())
    recorded = json.loads((run / "meta.json").read_text())["init_policy"]
    assert recorded["steps"] == learned.Checkpoint("tiny").meta["steps"] and len(recorded["policy_sha256"]) == 64
    # A checkpoint that does not fit fails before anything is written, or, for another network, leaves no folder.
    assert train.main([*cli, "init_policy=nope"]) == 2
    assert train.main([*cli, "init_policy=tiny", "policy_kwargs.width=16"]) == 2
    assert sorted(p.name for p in runs.iterdir()) == ["grasp_clutter_dqn-seed0"]


def test_her_pipeline_runs_with_vectorised_envs(tmp_path):
    overrides = [
        "total_steps=200",
        "n_envs=2",
        "algo_kwargs.learning_starts=100",
        "algo_kwargs.buffer_size=1000",
        "eval_every=200",
        "eval_episodes=1",
        "final_eval_episodes=1",
        "checkpoint_every=200",
    ]
    config = str(CONFIGS / "lift_sac_her.yaml")  # with training envs that start some episodes holding the object
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress", *overrides]) == 0
    final = json.loads((tmp_path / "lift_sac_her-seed0" / "final.json").read_text())
    assert final["steps"] == 200 and final["metrics"]["episodes"] == 1
    card = (tmp_path / "lift_sac_her-seed0" / "card.md").read_text()
    curriculum = load_config(config, []).train_env_kwargs
    assert curriculum and f"training envs also {json.dumps(curriculum)}" in card


def test_learning_rate_decays_linearly_over_total_steps_also_when_resumed(tmp_path, monkeypatch):
    decay = "algo_kwargs.learning_rate={start: 0.001, end: 0.0001}"
    config = str(CONFIGS / "grasp_clutter_dqn.yaml")
    cli = ["--config", config, "--runs", str(tmp_path), "--no-progress", *TINY_DQN, decay, "total_steps=6"]
    assert train.main(cli) == 0
    rates = []
    original = HeightmapDQN.train

    def recording_train(self, *args, **kwargs):
        original(self, *args, **kwargs)
        rates.append((self.num_timesteps, self.policy.optimizer.param_groups[0]["lr"]))

    monkeypatch.setattr(HeightmapDQN, "train", recording_train)
    assert train.main(["--resume", str(tmp_path / "grasp_clutter_dqn-seed0"), "total_steps=12", "--no-progress"]) == 0
    assert [steps for steps, _ in rates] == [7, 8, 9, 10, 11, 12]
    for steps, rate in rates:  # progress counts from the run's first step to its total_steps, across sessions
        assert rate == pytest.approx(1e-3 + (1e-4 - 1e-3) * steps / 12)

    rates.clear()  # a resumed run may change the learner's settings: they reach the loaded model
    run = str(tmp_path / "grasp_clutter_dqn-seed0")
    assert train.main(["--resume", run, "total_steps=14", "algo_kwargs.learning_rate=0.0005", "--no-progress"]) == 0
    assert rates == [(13, pytest.approx(5e-4)), (14, pytest.approx(5e-4))]
    assert "learning_rate: 0.0005" in (tmp_path / "grasp_clutter_dqn-seed0" / "config.yaml").read_text()
    sessions = json.loads((tmp_path / "grasp_clutter_dqn-seed0" / "meta.json").read_text())["resumed"]
    assert [(r["after_steps"], r["overrides"]) for r in sessions] == [
        (6, ["total_steps=12"]),
        (12, ["total_steps=14", "algo_kwargs.learning_rate=0.0005"]),
    ]  # config.yaml keeps only the latest values: the card tells the stages apart
    card = (tmp_path / "grasp_clutter_dqn-seed0" / "card.md").read_text()
    assert (
        "| sessions | resumed at step 6 with `total_steps=12`; at step 12 with `total_steps=14` "
        "`algo_kwargs.learning_rate=0.0005` |" in card
    )


def test_resume_refuses_changes_to_what_built_the_model(finished_run, capsys):
    saved = (finished_run / "config.yaml").read_text()
    for override in ("seed=5", "policy_kwargs.rotations=8", "algo_kwargs.buffer_size=7"):
        assert train.main(["--resume", str(finished_run), override, "--no-progress"]) == 2
        assert "a resumed run cannot change" in capsys.readouterr().err
    assert (finished_run / "config.yaml").read_text() == saved


@pytest.mark.slow
def test_smoke_training_learns_to_grasp(tmp_path):
    """CI's smoke training (~4 min on 2 cores): 300 grasps in the pixel mode lift grasp success on held-out seeds."""
    config = str(CONFIGS / "smoke_grasp_dqn.yaml")
    assert train.main(["--config", config, "--runs", str(tmp_path), "--no-progress"]) == 0
    run = tmp_path / "smoke_grasp_dqn-seed0"
    evaluations = [json.loads(line) for line in (run / "evaluations.jsonl").read_text().splitlines()]
    untrained = evaluations[0]["metrics"]["grasp_success"]["rate"]
    trained = json.loads((run / "final.json").read_text())["metrics"]["grasp_success"]["rate"]
    assert evaluations[0]["steps"] == 0
    assert trained >= untrained + 0.15 and trained >= 0.55, (untrained, trained)


@pytest.mark.unit
def test_evaluation_plays_the_seeds_it_is_given():
    """Validation and the held-out test must be different episodes: evaluate_policy seeds from first_seed."""
    from panda_grasp_env.agents.learning.training import evaluate_policy

    class Still:  # a stand-in policy: do nothing
        def predict(self, observation, deterministic=True):
            return np.zeros(4, dtype=np.float32), None

    config = TrainConfig(name="s", env_id="PandaPush-v0", algo="sac", total_steps=1, max_episode_steps=2, eval_seed=7)
    assert evaluate_policy(Still(), config, 2)["seeds"] == [7, 8]
    assert evaluate_policy(Still(), config, 2, first_seed=100)["seeds"] == [100, 101]


def test_retest_runs_the_final_test_again_without_training(finished_run, capsys):
    before = json.loads((finished_run / "final.json").read_text())
    (finished_run / "final.json").unlink()
    assert train.main(["--retest", str(finished_run)]) == 0
    after = json.loads((finished_run / "final.json").read_text())
    assert after["metrics"] == before["metrics"] and after["steps"] == 12  # deterministic, same seeds
    assert json.loads((finished_run / "progress.json").read_text())["steps"] == 12  # nothing trained
    assert "final: success" in capsys.readouterr().out


def test_retest_of_a_corrupt_policy_is_one_error_line(finished_run, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(finished_run, broken)
    (broken / "best_policy.safetensors").write_bytes(b"not weights")
    assert train.main(["--retest", str(broken)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot load the best policy of") and "best_policy.safetensors" in err
    assert "Traceback" not in err


def test_resume_from_a_corrupt_checkpoint_is_one_error_line_and_no_session(finished_run, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(finished_run, broken)
    (broken / "latest.zip").write_bytes(b"not a zip")
    sessions = json.loads((broken / "meta.json").read_text())["resumed"]
    assert train.main(["--resume", str(broken), "total_steps=14", "--no-progress", "--trust"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot resume") and "Traceback" not in err
    assert json.loads((broken / "meta.json").read_text())["resumed"] == sessions  # the failed session left no record


def test_resume_rebuilds_a_policy_pickled_under_a_retired_module_name(finished_run, tmp_path):
    """Checkpoints written before the package's import names moved pickle their policy class as
    ``agents.heightmap_policy:...``; a resume builds the config's own class instead of unpickling that name."""
    import base64
    import pickle
    import shutil
    import sys
    import types
    import zipfile

    retired = types.ModuleType("retired_agents")
    retired.HeightmapQPolicy = type("HeightmapQPolicy", (), {"__module__": "retired_agents"})
    sys.modules["retired_agents"] = retired
    try:
        serialized = base64.b64encode(pickle.dumps(retired.HeightmapQPolicy)).decode()
    finally:
        del sys.modules["retired_agents"]
    old = tmp_path / "old"
    shutil.copytree(finished_run, old)
    with zipfile.ZipFile(finished_run / "latest.zip") as source, zipfile.ZipFile(old / "latest.zip", "w") as target:
        for item in source.infolist():
            content = source.read(item)
            if item.filename == "data":
                data = json.loads(content)
                data["policy_class"][":serialized:"] = serialized
                content = json.dumps(data).encode()
            target.writestr(item, content)
    assert train.main(["--resume", str(old), "total_steps=14", "--no-progress", "--trust"]) == 0
    with zipfile.ZipFile(old / "latest.zip") as rewritten:
        policy_class = json.loads(rewritten.read("data"))["policy_class"]
    assert policy_class["__module__"] == "panda_grasp_env.agents.learning.heightmap_policy"
    assert isinstance(load_policy(old / "best_policy"), HeightmapQPolicy)


def test_retest_runs_on_a_shipped_checkpoint_too(finished_run, tmp_path, monkeypatch):
    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path)
    shipped = ship(finished_run, "tiny")  # policy.zip, no progress.json: the run's totals are in final.json
    before = json.loads((shipped / "final.json").read_text())
    assert train.main(["--retest", str(shipped)]) == 0
    after = json.loads((shipped / "final.json").read_text())
    assert after["metrics"] == before["metrics"] and after["steps"] == before["steps"] == 12
    assert not (shipped / "progress.json").exists()
    assert after["test_commit"]  # the code the test ran on, which a card names when it differs from training's
    # The figures it replaces stay beside the new ones (final.json and the card), newest last.
    assert after["earlier"][-1] == {"test_commit": before["test_commit"], "metrics": before["metrics"]}
    card = (shipped / "card.md").read_text()
    assert "Earlier tests of this policy" in card
    assert card.startswith("# tiny\n\nShipped from the run `")  # named as shipped, not as the run was
    # Shipped to act with its FailureMemory, it is retested so, and its card says which test had it.
    shipped = ship(finished_run, "tiny", avoid_failures=True)
    assert train.main(["--retest", str(shipped)]) == 0
    assert train.main(["--retest", str(shipped)]) == 0
    final = json.loads((shipped / "final.json").read_text())
    assert final["avoid_failures"] and final["earlier"][-1]["avoid_failures"]
    assert "avoid_failures" not in final["earlier"][0]  # the run's own test, without it
    card = (shipped / "card.md").read_text()
    assert "It acts as shipped, with its `FailureMemory`" in card and ", with its `FailureMemory`:" in card
    assert "disturbed objects per action" in card  # collateral, for primitive tasks


@pytest.mark.unit
def test_ctrl_c_before_the_first_checkpoint_says_so_and_leaves_a_clean_start(tmp_path, monkeypatch, capsys):
    """Interrupted while setting up (before any checkpoint): no claim of a checkpoint, no half-made folder that
    --resume would refuse; the same command starts again."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run_kinds, "train", interrupted)  # a policy run's training (train.py runs it by its kind)
    cli = ["--config", str(CONFIGS / "push_sac_her.yaml"), "--runs", str(tmp_path), "--no-progress"]
    assert train.main(cli) == 130
    message = capsys.readouterr().err
    assert "before the first checkpoint: nothing was saved" in message and "checkpoint saved" not in message
    assert not (tmp_path / "push_sac_her-seed0").exists()


@pytest.mark.parametrize("moment", ["reading the run", "SB3 setting up"])
def test_ctrl_c_while_setting_up_is_one_line_and_the_same_command_starts_again(tmp_path, monkeypatch, capsys, moment):
    """Interrupted while the config and the run folder are read, or while SB3 sets up inside ``learn`` (resetting
    the envs, before the run's callback starts): one line, exit 130, no folder (SB3's case was an
    AttributeError traceback, and a folder left behind)."""
    from stable_baselines3.common.base_class import BaseAlgorithm

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    if moment == "reading the run":  # a policy run's start (train.py runs it by its kind)
        monkeypatch.setitem(run_kinds.RUN_KINDS, None, dataclasses.replace(run_kinds.POLICY, start=interrupted))
    else:
        monkeypatch.setattr(BaseAlgorithm, "_setup_learn", interrupted)
    cli = ["--config", str(CONFIGS / "grasp_clutter_dqn.yaml"), "--runs", str(tmp_path), "--no-progress", *TINY_DQN]
    assert train.main(cli) == 130
    err = capsys.readouterr().err
    assert err.strip().count("\n") == 0 and "Traceback" not in err and "checkpoint saved" not in err
    assert "nothing was" in err and "the same command" in err
    assert not (tmp_path / "grasp_clutter_dqn-seed0").exists()


def test_a_signal_that_lands_in_a_garbage_collection_callback_still_interrupts_the_job(monkeypatch):
    """Raised inside a gc callback (jax installs one), a KeyboardInterrupt is printed as ignored and the job goes
    on: a Ctrl-C during train.py's set-up was lost so, and the run trained to its end."""
    import gc
    import os
    import signal
    import time

    from panda_grasp_env.tooling.runs import interrupt_on_signals

    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    sent = []

    def callback(phase, info):
        if not sent:
            sent.append(phase)
            os.kill(os.getpid(), signal.SIGINT)  # delivered here, inside the callback

    interrupt_on_signals()
    gc.callbacks.append(callback)
    try:
        with pytest.raises(KeyboardInterrupt, match="signal 2"):
            gc.collect()
            deadline = time.monotonic() + 3
            while time.monotonic() < deadline:
                time.sleep(0.001)
    finally:
        gc.callbacks.remove(callback)
        for number, handler in handlers.items():
            signal.signal(number, handler)
    assert sent


@pytest.mark.unit
@pytest.mark.parametrize(
    ("config", "setting", "message"),
    [
        ("push_grasp_dqn.yaml", "algo_kwargs.buffer_size=200000", r"algo_kwargs.buffer_size=200000: a buffer of"),
        ("push_ppo.yaml", "algo_kwargs.n_steps=100000000", r"algo_kwargs.n_steps=100000000: a buffer of"),
    ],
)
def test_a_buffer_past_the_bound_is_refused_before_sb3_allocates_it(tmp_path, config, setting, message):
    from panda_grasp_env.agents.learning.training import build_model

    loaded = load_config(CONFIGS / config, [setting, "n_envs=1", "vec_env=dummy"])
    env = make_vec_env(loaded)
    try:
        with pytest.raises(ValueError, match=message + r" .* GiB, more than the 12 GiB a run may"):
            build_model(loaded, env, None)
    finally:
        env.close()
