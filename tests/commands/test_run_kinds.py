"""train.py runs each kind of run by the kind that its config, run folder or study declares (``run_kinds``),
never by which files a folder holds."""

import json

import pytest

from panda_grasp_env.commands import train
from panda_grasp_env.commands.run_kinds import FALL_DYNAMICS, POLICY, declared_kind, folder_kind


@pytest.mark.unit
def test_a_config_declares_its_kind_and_a_policys_declares_none():
    assert declared_kind({"name": "x"}, "c.yaml") is POLICY
    assert declared_kind({"kind": "fall_dynamics"}, "c.yaml") is FALL_DYNAMICS
    for kind in ("falls", 3, ["fall_dynamics"]):
        with pytest.raises(ValueError, match=r"c.yaml: kind=.* is no kind of run: one of \['fall_dynamics'\]"):
            declared_kind({"kind": kind}, "c.yaml")


@pytest.mark.unit
def test_a_folder_is_run_by_the_kind_it_declares_whatever_files_it_holds(tmp_path, capsys):
    dataset = tmp_path / "dataset"
    dataset.mkdir()
    (dataset / "metadata.json").write_text("{}")
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text(f"kind: fall_dynamics\nname: tiny\ndataset: {dataset}\n")
    (run / "latest.zip").write_bytes(b"")  # a policy's checkpoint: the declared kind decides, not the files
    assert folder_kind(run) == ("run", FALL_DYNAMICS)
    assert train.main(["--resume", str(run), "--no-progress"]) == 2
    assert "has no checkpoint (latest.pt) to resume from" in capsys.readouterr().err
    assert train.main(["--ship", str(run), "--name", "tiny"]) == 2
    assert "is not a finished fall-dynamics run" in capsys.readouterr().err
    assert train.main(["--config", str(run / "config.yaml"), "--seeds", "0,1"]) == 2
    assert "--seeds trains policies" in capsys.readouterr().err
    study = tmp_path / "study"
    study.mkdir()
    (study / "study.json").write_text(json.dumps({"seeds": [0, 1], "config": {"name": "tiny", "algo": "dqn"}}))
    assert folder_kind(study) == ("study", POLICY)  # the config it trained declares no kind
    (dataset / "study.json").write_text(json.dumps({"seeds": [0, 1]}))
    with pytest.raises(ValueError, match="records no config it trained: not a study over seeds"):
        folder_kind(dataset)
    with pytest.raises(ValueError, match="is neither a run folder .* nor a study over seeds"):
        folder_kind(tmp_path)
    assert train.main(["--retest", str(tmp_path)]) == 2
    assert "is not a run folder (no config.yaml)" in capsys.readouterr().err
