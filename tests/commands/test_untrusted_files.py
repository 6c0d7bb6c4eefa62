"""Files someone else wrote, handed to the project's readers: every bad one is refused at once, with one
``ValueError`` that names the file, and nothing is read past the bound.

The readers: the bounded JSON / YAML / JSON-lines readers themselves (``tooling.reading``), a Minari dataset's
``metadata.json``, a checkpoint's ``config.yaml``, an ``evaluate.py --config`` protocol file, an
``evaluate.py --resume`` episode log, a ``train.py --config`` (the reader of a run folder's config.yaml too)
and a run's ``progress.json`` (``train.py --resume``; a checkpoint's ``final.json`` under ``--retest``).  The
files: a FIFO, ``/dev/zero`` (the device, and a symlink to it), a directory, a file past the size bound, JSON
and YAML nested 10,000 deep, a 341-byte YAML alias bomb, a self-referencing alias, and bytes that are not UTF-8.
"""

from __future__ import annotations

import json
import os
import time
import tracemalloc
from pathlib import Path

import pytest

from panda_grasp_env.agents.evaluation.runner import _load as load_resume_log
from panda_grasp_env.agents.learning.config import read_config as read_training_config
from panda_grasp_env.agents.learning.datasets import dataset_metadata
from panda_grasp_env.agents.policies.learned import read_config
from panda_grasp_env.commands.evaluate import protocol_argv
from panda_grasp_env.registration import ENTRY_POINT
from panda_grasp_env.tooling.reading import read_json, read_json_lines, read_yaml
from panda_grasp_env.tooling.runs import read_progress

pytestmark = [pytest.mark.unit, pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="FIFOs and devices: Linux")]

#: Nine levels of nine aliases each: 9**10 nodes once expanded, from 341 bytes.
ALIAS_BOMB = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{b}: &{b} [{', '.join([f'*{a}'] * 9)}]\n" for a, b in zip("abcdefghi", "bcdefghij")
)


def bad_file(folder: Path, kind: str, name: str) -> Path:
    """A file called ``name`` in ``folder`` that is ``kind``."""
    path = folder / name
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device link":
        path.symlink_to("/dev/zero")
    elif kind == "directory":
        path.mkdir()
    elif kind == "oversized":  # 300 MiB of zeros, sparse: past every bound
        path.touch()
        os.truncate(path, 300 << 20)
    elif kind == "deep json":
        path.write_text("[" * 10_000 + "]" * 10_000 + "\n")
    elif kind == "deep yaml":
        path.write_text("{a: " * 10_000 + "1" + "}" * 10_000 + "\n")
    elif kind == "alias bomb":
        path.write_text(ALIAS_BOMB)
    elif kind == "self alias":
        path.write_text("a: &a [*a]\n")
    elif kind == "not utf-8":
        path.write_bytes(b'{"a":\n1,\n"\xff"}\n')
    return path


KINDS = ("fifo", "device link", "directory", "oversized", "deep json", "deep yaml", "alias bomb", "self alias")
KINDS += ("not utf-8",)


def resume_log(path: Path) -> object:
    """``evaluate.py --resume``'s reading of an episode log."""
    return load_resume_log(path, "abc1234", set())


READERS = {
    "json": (lambda path: read_json(path, 16 << 20), "data.json"),
    "json lines": (lambda path: list(read_json_lines(path, 16 << 20)), "log.jsonl"),
    "yaml": (lambda path: read_yaml(path, 16 << 20), "data.yaml"),
    "dataset metadata": (lambda path: dataset_metadata(path.parent), "metadata.json"),
    "checkpoint config": (read_config, "config.yaml"),
    "protocol file": (protocol_argv, "protocol.yaml"),
    "resume log": (resume_log, "episodes.jsonl"),
    "training config": (read_training_config, "config.yaml"),
    "run totals": (read_progress, "progress.json"),
}


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("reader", sorted(READERS))
def test_a_bad_file_is_refused_at_once_in_one_line_naming_it(tmp_path, reader, kind):
    read, name = READERS[reader]
    path = bad_file(tmp_path, kind, name)
    tracemalloc.start()
    start = time.perf_counter()
    try:
        with pytest.raises(ValueError) as refused:
            read(path)
        seconds, (_, peak) = time.perf_counter() - start, tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(refused.value)
    assert str(path) in message and "\n" not in message, message
    assert seconds < 1.0 and peak < 64 << 20  # nothing read past the bound


def test_a_bad_line_of_a_log_is_named_by_its_number(tmp_path):
    path = tmp_path / "log.jsonl"
    path.write_text('{"a": 1}\n\n{"a": \n{"b": 2}\n')
    with pytest.raises(ValueError, match=r"log\.jsonl line 3"):
        list(read_json_lines(path, 1 << 10))


def test_yaml_anchors_that_stay_small_still_read(tmp_path):
    path = tmp_path / "ok.yaml"
    path.write_text("base: &base {lr: 0.001, gamma: 0.99}\nrun: *base\n")
    assert read_yaml(path, 1 << 10) == {"base": {"lr": 0.001, "gamma": 0.99}, "run": {"lr": 0.001, "gamma": 0.99}}


BOX = '{"type": "Box", "dtype": "float32", "shape": [3], "low": [0, 0, 0], "high": [1, 1, 1]}'


def write_metadata(folder: Path, **fields) -> Path:
    metadata = {"observation_space": BOX, "action_space": BOX, **fields}
    (folder / "metadata.json").write_text(json.dumps(metadata))
    return folder


def test_a_dataset_whose_space_nests_ten_thousand_deep_is_refused_naming_its_metadata(tmp_path):
    folder = write_metadata(tmp_path, observation_space="[" * 10_000 + "]" * 10_000)
    with pytest.raises(ValueError, match=r"metadata\.json: observation_space nests 10000 levels deep"):
        dataset_metadata(folder)


@pytest.mark.parametrize("taken", ["max_episode_steps", "id"])
def test_an_env_spec_whose_kwargs_hold_makes_own_parameters_is_refused(tmp_path, taken):
    spec = {"id": "PandaPush-v0", "entry_point": ENTRY_POINT, "kwargs": {taken: 5}}
    folder = write_metadata(tmp_path, env_spec=json.dumps(spec))
    with pytest.raises(ValueError, match=f"metadata.json: env_spec keyword arguments \\['{taken}'\\]"):
        dataset_metadata(folder)


MANY_BOXES = {"type": "Box", "dtype": "float64", "shape": [1 << 22], "low": 0, "high": 1}


@pytest.mark.parametrize(
    ("fields", "message"),
    [
        ({"action_space": '{"type": "Discrete", "n": 1' + "0" * 30 + ', "start": 0}'}, "Discrete n and start"),
        (
            {"observation_space": json.dumps({"type": "Dict", "subspaces": {f"b{i}": MANY_BOXES for i in range(64)}})},
            r"its spaces hold more than 4194304 elements in all",
        ),
        ({"action_space": '{"type": "Text", "max_length": 10}'}, r"not a space of a kind this project records"),
        ({"total_episodes": 10**15}, r"total_episodes must be a whole number from 0 to 1000000000"),
        ({"total_steps": "12"}, r"total_steps must be a whole number"),
    ],
)
def test_a_dataset_whose_spaces_or_counts_would_not_fit_is_refused_before_minari_allocates(tmp_path, fields, message):
    """Each within the bound of its own field (a 3 kB metadata file), refused in one line naming the file."""
    tracemalloc.start()
    started = time.perf_counter()
    with pytest.raises(ValueError, match=message) as refused:
        dataset_metadata(write_metadata(tmp_path, **fields))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert "metadata.json" in str(refused.value) and "\n" not in str(refused.value)
    assert time.perf_counter() - started < 1.0 and peak < 64 << 20


@pytest.mark.parametrize(
    "fields",
    [
        {"action_space": '{"type": "Discrete", "n": 1' + "0" * 30 + ', "start": 0}'},
        {"observation_space": '{"type": "Dict", "subspaces": {"a": ' * 10_000 + BOX + "}}" * 10_000},
        {"total_episodes": 10**15},
    ],
)
def test_train_py_refuses_a_demonstration_dataset_before_it_makes_a_run_folder(tmp_path, capsys, fields):
    """One error line naming the metadata, no "run folder:" line, no folder made and removed again."""
    from panda_grasp_env.commands import train

    (tmp_path / "ns" / "demos-v0" / "data").mkdir(parents=True)
    write_metadata(tmp_path / "ns" / "demos-v0" / "data", **fields)
    runs = tmp_path / "runs"
    demonstrations = f"algo_kwargs.demonstrations={{dataset: ns/demos-v0, episodes: 1, path: {tmp_path}}}"
    config = Path(__file__).parents[2] / "configs" / "stack_bc.yaml"
    started = time.perf_counter()
    assert train.main(["--config", str(config), "--runs", str(runs), "--no-progress", demonstrations]) == 2
    assert time.perf_counter() - started < 1.0
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith(f"error: {tmp_path}/ns/demos-v0/data/metadata.json")
    assert not runs.exists() or not any(runs.iterdir())
