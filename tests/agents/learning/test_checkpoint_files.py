"""Checkpoints are data: no file a checkpoint, run or model folder holds runs code when it is loaded.

Each payload below is a pickle (or an importable module) that would create a marker file if it ran; every
entry point that reads such a file must refuse it with a ``ValueError`` naming it, and the marker must not
appear."""

from __future__ import annotations

import builtins
import json
import pickle
import shutil
import sys
from collections import Counter

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from testkit import CONFIGS, TINY_DQN

from panda_grasp_env.agents.learning.policy_files import (
    export_sb3,
    load_policy,
    load_sb3,
    policy_paths,
    save_policy,
    space_from_json,
    space_to_json,
)
from panda_grasp_env.agents.learning.records import ship
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.commands import evaluate, train
from panda_grasp_env.tooling.runs import sign_run_files


class Payload:
    """Unpickling this opens ``marker`` for writing (creating it): harmless, and visible."""

    def __init__(self, marker) -> None:
        self.marker = str(marker)

    def __reduce__(self):
        return builtins.open, (self.marker, "w")


def write_payload(path, marker) -> None:
    with open(path, "wb") as file:
        pickle.dump(Payload(marker), file, protocol=2)


@pytest.fixture
def marker(tmp_path):
    path = tmp_path / "payload-ran"
    yield path
    assert not path.exists(), "a payload ran"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):

    runs = tmp_path_factory.mktemp("runs")
    config = str(CONFIGS / "grasp_clutter_dqn.yaml")
    assert train.main(["--config", config, "--runs", str(runs), "--no-progress", *TINY_DQN, "total_steps=6"]) == 0
    return runs / "grasp_clutter_dqn-seed0"


@pytest.fixture
def shipped(tiny_run, tmp_path, monkeypatch):
    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    return ship(tiny_run, "tiny")


def pickled_checkpoint(shipped, marker):
    """The shipped folder as an SB3-zip checkpoint whose policy.zip is a payload."""
    for path in policy_paths(shipped / "policy"):
        path.unlink()
    write_payload(shipped / "policy.zip", marker)
    return shipped


def test_a_pickled_policy_zip_is_refused_unless_trusted(shipped, marker):
    pickled_checkpoint(shipped, marker)
    with pytest.raises(ValueError, match=r"policy.zip is an SB3 pickle .* trust=True"):
        learned.LearnedAgent("tiny")
    with pytest.raises(ValueError, match=r"policy.zip is an SB3 pickle"):
        learned.Checkpoint(shipped).load_policy()


@pytest.mark.unit
def test_a_class_name_outside_the_allow_list_is_never_imported(shipped, tmp_path, marker, monkeypatch):
    module = tmp_path / "payload_module.py"
    module.write_text(f"open({str(marker)!r}, 'w')\nclass Evil: pass\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    facts = json.loads((shipped / "policy.json").read_text())
    (shipped / "policy.json").write_text(json.dumps({**facts, "policy_class": "payload_module:Evil"}))
    with pytest.raises(ValueError, match="policy class 'payload_module:Evil' is not one this project loads"):
        learned.LearnedAgent("tiny")
    # An argument class likewise.
    facts["arguments"]["optimizer_class"] = {"__class__": "payload_module:Evil"}
    (shipped / "policy.json").write_text(json.dumps(facts))
    with pytest.raises(ValueError, match="argument class 'payload_module:Evil' is not one"):
        load_policy(shipped / "policy")
    # The same name in checkpoint.json, for an SB3 zip loaded with trust: refused before anything is read.
    pickled_checkpoint(shipped, marker)
    meta = json.loads((shipped / "checkpoint.json").read_text())
    (shipped / "checkpoint.json").write_text(json.dumps({**meta, "policy_class": "payload_module:Evil"}))
    with pytest.raises(ValueError, match="policy class 'payload_module:Evil' is not one"):
        learned.LearnedAgent("tiny", trust=True)
    assert "payload_module" not in sys.modules


@pytest.mark.unit
def test_evaluate_refuses_a_payload_checkpoint_with_one_error_line(shipped, tmp_path, marker, capsys):
    pickled_checkpoint(shipped, marker)
    argv = ["--agents", "tiny", "--tasks", "Grasp", "--seeds", "1", "--no-video", "--out", str(tmp_path / "out")]
    assert evaluate.main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and "policy.zip is an SB3 pickle" in err and "Traceback" not in err


@pytest.mark.unit
def test_init_policy_refuses_a_payload_checkpoint(shipped, tmp_path, marker, capsys):

    pickled_checkpoint(shipped, marker)
    runs = tmp_path / "runs"
    cli = ["--config", str(CONFIGS / "grasp_clutter_dqn.yaml"), "--runs", str(runs), "--no-progress", *TINY_DQN]
    assert train.main([*cli, "init_policy=tiny"]) == 2
    assert "policy.zip is an SB3 pickle" in capsys.readouterr().err
    assert not runs.exists() or not any(runs.iterdir())


@pytest.mark.unit
def test_retest_refuses_a_run_whose_best_policy_is_a_pickle(tiny_run, tmp_path, marker, capsys):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    for path in policy_paths(run / "best_policy"):
        path.unlink()
    write_payload(run / "best_policy.zip", marker)
    (run / "best.json").write_text(json.dumps({"steps": 6, "policy_class": "builtins:eval"}))
    assert train.main(["--retest", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cannot load the best policy of") and "best_policy.json" in err


@pytest.mark.unit
@pytest.mark.parametrize("name", ["replay.pkl", "latest.zip"])
def test_resume_loads_only_the_pickles_this_users_job_signed_in_that_folder(tiny_run, tmp_path, marker, capsys, name):
    run = tmp_path / "run"
    shutil.copytree(tiny_run, run)
    # A copied or moved run is not the folder that wrote it: refused until the user says --trust.
    assert train.main(["--resume", str(run), "total_steps=8", "--no-progress"]) == 2
    assert "latest.zip was not written by this user's job in this folder" in capsys.readouterr().err
    # Signed here, then one file swapped for a payload: refused, naming it.
    sign_run_files(run, ["latest.zip", "replay.pkl"])
    write_payload(run / name, marker)
    assert train.main(["--resume", str(run), "total_steps=8", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{name} was not written by this user's job" in err and "--trust" in err
    assert json.loads((run / "progress.json").read_text())["steps"] == 6  # nothing trained


@pytest.mark.unit
def test_the_fall_model_loader_refuses_a_payload(tmp_path, marker):
    from panda_grasp_env.agents.learning.falls.model import load_fall_model

    write_payload(tmp_path / "model.pt", marker)
    with pytest.raises(ValueError, match=f"cannot load fall-dynamics checkpoint {tmp_path / 'model.pt'}"):
        load_fall_model(tmp_path / "model.pt")


@pytest.mark.unit
def test_policy_files_round_trip_with_identical_actions(shipped, tmp_path):
    policy = learned.Checkpoint("tiny").load_policy()
    save_policy(policy, tmp_path / "again")
    again = load_policy(tmp_path / "again")
    observations = np.random.default_rng(0).integers(0, 256, (8, *policy.observation_space.shape), np.uint8)
    assert np.array_equal(policy.predict(observations)[0], again.predict(observations)[0])
    # The SB3 export reads back, with trust, to the same weights.
    exported = export_sb3(policy, tmp_path / "policy.zip")
    with pytest.raises(ValueError, match="SB3 pickle"):
        load_sb3(exported, "panda_grasp_env.agents.heightmap_policy:HeightmapQPolicy")
    trusted = load_sb3(exported, "panda_grasp_env.agents.heightmap_policy:HeightmapQPolicy", trust=True)
    assert all(th.equal(v, trusted.state_dict()[k]) for k, v in policy.state_dict().items())
    # Weights that are not the ones the JSON records are refused.
    weights = policy_paths(tmp_path / "again")[1]
    weights.write_bytes(policy_paths(shipped / "policy")[1].read_bytes()[:-4] + b"\0\0\0\0")
    with pytest.raises(ValueError, match="is not the weights"):
        load_policy(tmp_path / "again")


@pytest.mark.unit
def test_policy_files_name_the_heightmap_policy_by_a_name_its_module_can_move_under():
    """Shipped files name the policy class as it was first saved; moving its module renames nothing in them."""
    from panda_grasp_env.agents.learning.heightmap_policy import HeightmapQPolicy
    from panda_grasp_env.agents.learning.policy_files import class_name, policy_classes

    folders = [learned.CHECKPOINTS / name for name in learned.available_checkpoints()]
    files = [
        json.loads((folder / file).read_text()) for folder in folders for file in ("policy.json", "checkpoint.json")
    ]
    named = {facts["policy_class"] for facts in files if "policy_class" in facts}
    assert named <= set(policy_classes())
    heightmap = class_name(HeightmapQPolicy)
    assert heightmap in named and not heightmap.startswith(HeightmapQPolicy.__module__)


@pytest.mark.unit
def test_a_policy_with_one_feature_extractor_for_actor_and_critics_round_trips(tmp_path):
    """SB3's SAC / TQC policies leave ``share_features_extractor`` out of their constructor arguments; a policy
    file keeps it, or the critics would be rebuilt with their own extractors and the weights would not fit."""
    from sb3_contrib.tqc.policies import MultiInputPolicy

    space = gym.spaces.Dict(
        {"image": gym.spaces.Box(0, 255, (3, 36, 36), np.uint8), "goal": gym.spaces.Box(-1, 1, (3,), np.float32)}
    )
    policy = MultiInputPolicy(
        space, gym.spaces.Box(-1, 1, (4,), np.float32), lambda _: 1e-3, net_arch=[16], share_features_extractor=True
    )
    save_policy(policy, tmp_path / "shared")
    again = load_policy(tmp_path / "shared")
    assert again.share_features_extractor and again.critic.features_extractor is again.actor.features_extractor
    observation = space.sample()
    assert np.array_equal(
        policy.predict(observation, deterministic=True)[0], again.predict(observation, deterministic=True)[0]
    )
    # The SB3 export too: SB3's own policy.save drops the flag, and its load then fails on the weights.
    exported = MultiInputPolicy.load(str(export_sb3(policy, tmp_path / "shared.zip")), device="cpu")
    assert exported.critic.features_extractor is exported.actor.features_extractor
    assert np.array_equal(
        policy.predict(observation, deterministic=True)[0], exported.predict(observation, deterministic=True)[0]
    )


@pytest.mark.unit
@pytest.mark.parametrize(
    "space",
    [
        gym.spaces.Box(0, 255, (4, 8, 8), np.uint8),
        gym.spaces.Box(np.array([-1.0, 0.0]), np.array([1.0, np.inf]), dtype=np.float64),
        gym.spaces.Discrete(7, start=2),
        gym.spaces.MultiDiscrete([3, 16, 8, 8]),
        gym.spaces.MultiBinary(5),
        gym.spaces.Dict({"a": gym.spaces.Box(-1, 1, (3,), np.float32), "b": gym.spaces.Discrete(2)}),
    ],
)
def test_spaces_round_trip_through_json(space):
    assert space_from_json(json.loads(json.dumps(space_to_json(space)))) == space


@pytest.mark.unit
def test_unknown_space_descriptions_are_refused():
    with pytest.raises(ValueError, match="unknown space kind 'Graph'"):
        space_from_json({"Graph": {}})
    with pytest.raises(ValueError, match="malformed Box"):
        space_from_json({"Box": {"low": 0}})


# --- the run-signing key: a key someone else could know makes every signature forgeable -----------------


@pytest.fixture
def key_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    from panda_grasp_env.tooling import runs

    return runs


def key_path(tmp_path):
    return tmp_path / "state" / "panda_grasp_env" / "run_key"


@pytest.mark.unit
def test_the_signing_key_is_made_private_and_then_reused(key_home, tmp_path):
    key = key_home.run_key()
    path = key_path(tmp_path)
    assert len(key) == 32 and path.stat().st_mode & 0o777 == 0o600
    assert key_home.run_key() == key


@pytest.mark.unit
@pytest.mark.parametrize(
    "flaw", ["world-readable", "group-readable", "empty", "short", "long", "symlink", "dangling symlink", "directory"]
)
def test_a_signing_key_others_could_know_is_refused_with_the_mend(key_home, tmp_path, flaw):
    import os

    path = key_path(tmp_path)
    path.parent.mkdir(parents=True)
    real = tmp_path / "planted"
    real.write_bytes(os.urandom(32))
    real.chmod(0o600)
    if flaw in ("symlink", "dangling symlink"):
        path.symlink_to(real if flaw == "symlink" else tmp_path / "nothing")
    elif flaw == "directory":
        path.mkdir()
    else:
        size = {"empty": 0, "short": 16, "long": 64}.get(flaw, 32)
        path.write_bytes(os.urandom(size))
        path.chmod({"world-readable": 0o644, "group-readable": 0o640}.get(flaw, 0o600))
    with pytest.raises(ValueError, match=rf"run-signing key {path} .*delete it \(rm {path}\)") as refused:
        key_home.run_key()
    why = {
        "world-readable": "mode 0644",
        "group-readable": "mode 0640",
        "empty": "holds 0 bytes",
        "short": "holds 16 bytes",
        "long": "more than 32 bytes",
        "symlink": "is a symlink",
        "dangling symlink": "is a symlink",
        "directory": "is not a regular file",
    }
    assert why[flaw] in str(refused.value)
    # Nothing is signed or checked with it.
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "latest.zip").write_bytes(b"x")
    with pytest.raises(ValueError, match="run-signing key"):
        sign_run_files(tmp_path / "run", ["latest.zip"])


@pytest.mark.unit
def test_a_signing_key_of_another_user_is_refused(key_home, tmp_path, monkeypatch):
    import os

    key_home.run_key()
    monkeypatch.setattr(os, "getuid", lambda: os.stat(key_path(tmp_path)).st_uid + 1)
    with pytest.raises(ValueError, match=r"belongs to user id \d+, not to you"):
        key_home.run_key()


# --- checkpoints are bounded before anything is allocated, and malformed files name themselves -----------


@pytest.fixture
def sac_folder(tmp_path):
    """A copy of a shipped SB3 checkpoint (SAC MultiInputPolicy, net_arch [256, 256])."""
    folder = tmp_path / "lift"
    shutil.copytree(learned.CHECKPOINTS / "lift_sac_her", folder)
    return folder


#: A value ``dump`` writes as lists nested 5,000 deep (more than Python's JSON parser can read back).
DEEP = "__nested 5000 deep__"


def dump(facts) -> str:
    return json.dumps(facts).replace(json.dumps(DEEP), "[" * 5000 + "]" * 5000)


def edit_json(path, change):
    facts = json.loads(path.read_text())
    change(facts)
    path.write_text(dump(facts))


def set_box_shape(facts, shape):
    facts["arguments"]["observation_space"]["__space__"]["Dict"]["observation"]["Box"]["shape"] = shape


BOUNDS = {
    "wide layers": (
        lambda f: f["arguments"].update(net_arch=[20000, 20000]),
        r"arguments.net_arch\[0\] is 20000; network sizes and counts stay within 4096",
    ),
    "many parameters": (
        lambda f: f["arguments"].update(net_arch=[4096] * 8),
        r"arguments.net_arch \[4096, .*\] makes layers of at least \d+ parameters, more than",
    ),
    "parameters counted": (
        lambda f: f["arguments"].update(net_arch={"pi": [4000] * 3, "qf": [4000] * 3}, n_critics=10),
        r"arguments build a policy of \d+ parameters and buffer elements, more than the 64000000",
    ),
    "many critics": (lambda f: f["arguments"].update(n_critics=4096), r"arguments.n_critics is 4096, more than"),
    "long lists": (lambda f: f["arguments"].update(net_arch=[8] * 10_000), r"arguments.net_arch has 10000 entries"),
    "huge box": (
        lambda f: set_box_shape(f, [2_000_000_000]),
        r"arguments.observation_space: its spaces hold 2000000006 elements in all, more than 4194304",
    ),
    "big box": (
        lambda f: set_box_shape(f, [4096, 4096]),
        r"its spaces hold 16777222 elements in all, more than 4194304",
    ),
    "many boxes": (  # each within the bound, 64 of them 2 GB of float64: counted together
        lambda f: f["arguments"]["observation_space"]["__space__"].update(
            Dict={f"b{i}": {"Box": {"dtype": "float64", "low": 0, "high": 1, "shape": [1 << 22]}} for i in range(64)}
        ),
        r"arguments.observation_space: its spaces hold 268435456 elements in all, more than 4194304",
    ),
    "unknown key": (lambda f: f.update(note="hi"), r"policy.json: unknown key\(s\) \['note'\]"),
    "box of strings": (lambda f: set_box_shape(f, ["37"]), r"Box.shape must be a whole number"),
    "object dtype": (
        lambda f: f["arguments"]["action_space"]["__space__"]["Box"].update(dtype="object"),
        r"arguments.action_space.Box.dtype must be one of",
    ),
    "deep nesting": (lambda f: f["arguments"].update(net_arch=DEEP), r"nests 5002 levels deep, more than the 16"),
    "big file": (lambda f: f.update(padding="x" * (2 << 20)), r"policy.json holds \d+ bytes, more than the 1048576"),
    "format as a bool": (lambda f: f.update(format=True), r"policy.json is not a policy file of format 1"),
    "arguments as a list": (lambda f: f.update(arguments=[1, 2]), r"policy.json: arguments must be a mapping"),
}


@pytest.mark.unit
@pytest.mark.parametrize("bound", list(BOUNDS))
def test_policy_files_beyond_a_bound_are_refused_naming_the_file_and_the_field(sac_folder, bound):
    change, message = BOUNDS[bound]
    edit_json(sac_folder / "policy.json", change)
    with pytest.raises(ValueError, match=message) as refused:
        learned.LearnedAgent(sac_folder)
    assert str(sac_folder / "policy.json") in str(refused.value)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("rotations", "message"),
    [
        (40, r"parameters and buffer elements, more than the 64000000"),
        (2047, r"action_space.Discrete.n must be a whole number from 1 to 2147483647"),  # 51.8 GB of grids
    ],
)
def test_a_heightmap_policy_whose_rotation_grids_would_not_fit_is_refused_before_allocating(
    tmp_path, rotations, message
):
    """rotations x a 4 x 1024 x 1024 grid, every field within its own bound: its rotation buffers (not
    parameters) are counted too, on the meta device."""
    folder = tmp_path / "dqn"
    shutil.copytree(learned.CHECKPOINTS / "push_grasp_dqn", folder)

    def bomb(facts):
        arguments = facts["arguments"]
        arguments["rotations"] = rotations
        arguments["observation_space"]["__space__"]["Box"]["shape"] = [4, 1024, 1024]
        arguments["action_space"]["__space__"]["Discrete"]["n"] = 2 * rotations * 1024 * 1024

    edit_json(folder / "policy.json", bomb)
    with pytest.raises(ValueError, match=message):
        learned.LearnedAgent(folder)


def rewrite_weights(folder, change):
    """Change the tensors of ``folder``'s policy.safetensors with ``change(tensors)`` and record their digest."""
    from safetensors.torch import load_file, save_file

    from panda_grasp_env.tooling.runs import sha256

    weights = folder / "policy.safetensors"
    tensors = load_file(str(weights))
    change(tensors)
    save_file(tensors, str(weights))
    edit_json(folder / "policy.json", lambda f: f.update(weights_sha256=sha256(weights)))


@pytest.mark.unit
@pytest.mark.parametrize(
    ("change", "message"),
    [
        (lambda t: t.update({k: v.double() for k, v in list(t.items())[:1]}), r"is 'F64', not F32"),
        (lambda t: t.update({k: v.long() for k, v in list(t.items())[:1]}), r"is 'I64', not F32"),
        (lambda t: next(iter(t.values())).view(-1)[0].fill_(float("nan")), r"holds NaN or infinite weights"),
    ],
)
def test_weights_other_than_finite_float32_are_refused_naming_the_file(sac_folder, change, message):
    rewrite_weights(sac_folder, change)
    with pytest.raises(ValueError, match=message) as refused:
        learned.LearnedAgent(sac_folder)
    assert "policy.safetensors" in str(refused.value)


@pytest.mark.unit
def test_weights_beyond_the_size_limit_are_refused_before_they_are_read(sac_folder, monkeypatch):
    from panda_grasp_env.agents.learning import policy_files

    monkeypatch.setattr(policy_files, "MAX_WEIGHTS_BYTES", 1000)
    with pytest.raises(ValueError, match=r"policy.safetensors holds \d+ bytes, more than the 1000"):
        learned.LearnedAgent(sac_folder)


@pytest.mark.unit
@pytest.mark.parametrize(
    ("name", "text", "message"),
    [
        ("policy.json", "{not json", r"policy.json is not valid JSON"),
        ("policy.json", b"\xff\xfe{}", r"policy.json is not UTF-8 text"),
        ("checkpoint.json", "[1, 2]", r"checkpoint.json must be a JSON mapping of .* got a list"),
        ("checkpoint.json", '{"task": ', r"checkpoint.json is not valid JSON"),
        ("checkpoint.json", '{"task": "Lift"}', r"checkpoint.json: .*missing key\(s\) \['steps'\]"),
        ("checkpoint.json", '{"task": "Lift", "steps": true}', r"checkpoint.json: steps must be a JSON int"),
        (
            "checkpoint.json",
            '{"task": "Lift", "steps": 1, "avoid_failures": "no"}',
            r"checkpoint.json: avoid_failures must be a JSON boolean, got 'no'",
        ),
        (
            "checkpoint.json",
            '{"task": "Lift", "steps": 1, "avoid_failures": 0}',
            r"checkpoint.json: avoid_failures must be a JSON boolean",
        ),
        ("config.yaml", "- a list", r"config.yaml must be a mapping"),
        ("config.yaml", "a: [", r"config.yaml is not valid YAML"),
    ],
)
def test_malformed_checkpoint_files_raise_a_value_error_naming_the_file(sac_folder, name, text, message):
    path = sac_folder / name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    with pytest.raises(ValueError, match=message) as refused:
        learned.LearnedAgent(sac_folder)
    assert str(path) in str(refused.value)


def random_json(rng, depth=0):
    """A JSON value of a random type, size and depth: what a fuzzer writes into a checkpoint's metadata."""
    kind = rng.integers(0, 11 if depth < 6 else 7)
    if kind == 0:
        return None
    if kind == 1:
        return bool(rng.integers(2))
    if kind == 2:
        return int(rng.choice([0, 1, -1, 2, 37, 4096, 4097, 2**31, 2**63, 10**30, -(10**9)]))
    if kind == 3:
        return float(rng.choice([0.0, -1.5, 1e-300, 1e300, 3.25]))
    if kind == 4:
        return "".join(rng.choice(list('ab:._Box[]{}\\"é'), rng.integers(0, 12)))
    if kind == 5:
        return "x" * int(rng.choice([0, 10, 100_000]))
    if kind == 6:
        return DEEP if rng.random() < 0.3 else [[[[[[[[[[[[[[[[[[[1]]]]]]]]]]]]]]]]]]]
    if kind in (7, 8):
        return [random_json(rng, depth + 1) for _ in range(rng.integers(0, 5))]
    keys = ["Box", "Dict", "Discrete", "shape", "dtype", "low", "high", "n", "__space__", "__class__", "pi", "x"]
    return {str(rng.choice(keys)): random_json(rng, depth + 1) for _ in range(rng.integers(0, 4))}


def json_paths(value, path=()):
    yield path
    if isinstance(value, dict):
        for key, sub in value.items():
            yield from json_paths(sub, (*path, key))
    elif isinstance(value, list):
        for index, sub in enumerate(value):
            yield from json_paths(sub, (*path, index))


def fuzzed(facts, rng):
    """``facts`` with one value (anywhere: the root, a key, a list entry) replaced by a random one, or made deep."""
    paths = list(json_paths(facts))
    path = paths[rng.integers(len(paths))]
    new = random_json(rng)
    if not path:
        return new
    parent = facts
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = new
    return facts


def test_fuzzed_checkpoint_metadata_gives_only_value_errors_each_quickly(sac_folder):
    """Checkpoint metadata with random JSON values anywhere: loading succeeds or raises ValueError, nothing
    else, and each case is bounded (the limits refuse before anything large is allocated or built; the loose
    time bound below only catches a hang, such as the 30 s that net_arch [20000, 20000] took before)."""
    import time

    rng = np.random.default_rng(55)
    originals = {name: (sac_folder / name).read_text() for name in ("policy.json", "checkpoint.json")}
    outcomes, slowest = Counter(), 0.0
    for case in range(150):
        name = "policy.json" if case % 3 else "checkpoint.json"
        for original_name, text in originals.items():
            (sac_folder / original_name).write_text(text)
        (sac_folder / name).write_text(dump(fuzzed(json.loads(originals[name]), rng)))
        start = time.perf_counter()
        try:
            learned.LearnedAgent(sac_folder)
            outcomes["loaded"] += 1
        except ValueError as error:
            outcomes["ValueError"] += 1
            assert str(sac_folder) in str(error), error
        slowest = max(slowest, time.perf_counter() - start)
    print(f"fuzzed checkpoint metadata: {dict(outcomes)}, slowest case {slowest:.2f} s")
    assert outcomes["ValueError"] >= 100
    assert slowest < 10  # loose: a hang, not a speed
