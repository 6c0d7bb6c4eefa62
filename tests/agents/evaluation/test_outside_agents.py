"""What an author outside the package gets: agents under their own names, records that name the imported files,
``--help`` that lists what they registered, and the workspace's bounds by a public name."""

import hashlib
import json
import sys

import numpy as np
import pytest

import panda_grasp_env
from panda_grasp_env.agents.policies import registry
from panda_grasp_env.commands import evaluate

LAB_AGENT = '''
"""A lab's own agent: random primitives, seeing the scene as state, on Grasp only."""
from panda_grasp_env.agents.policies.random_agent import RandomAgent
from panda_grasp_env.agents.policies.registry import register_agent


@register_agent("lab_random", "Grasp", env_options={"max_episode_steps": 2})
def lab_random(env, seed):
    return RandomAgent(env.action_space, seed=seed)
'''


@pytest.fixture
def lab_agent(tmp_path):
    """The module above as a file; the agent it registers unregistered afterwards."""
    path = tmp_path / "lab_agent.py"
    path.write_text(LAB_AGENT)
    yield path
    registry.NAMED_AGENTS.pop("lab_random", None)
    sys.modules.pop("lab_agent", None)


def test_an_agent_registered_by_name_plays_its_tasks_and_the_records_name_its_file(lab_agent, tmp_path):
    out = tmp_path / "run"
    argv = ["--import", str(lab_agent), "--agents", "lab_random,random", "--tasks", "Grasp,Push", "--seeds", "2"]
    assert evaluate.main([*argv, "--no-video", "--out", str(out)]) == 0
    results = json.loads((out / "results.json").read_text())
    assert set(results["metrics"]) == {"lab_random/Grasp", "random/Grasp", "random/Push"}
    assert "registered for Grasp" in results["protocol"]["skipped"]["lab_random/Push"]
    lab_episodes = [e for e in results["episodes"] if e["spec"]["agent"] == "lab_random"]
    assert [e["actions"] for e in lab_episodes] == [2, 2]  # its env options reached its env
    digest = hashlib.sha256(lab_agent.read_bytes()).hexdigest()
    imported = {"module": str(lab_agent), "file": str(lab_agent.resolve()), "sha256": digest}
    assert results["protocol"]["imports"] == [imported]
    label = results["provenance"]["commit"]
    assert "+imports-" in label
    assert {json.loads(line)["commit"] for line in (out / "episodes.jsonl").read_text().splitlines()} == {label}
    assert digest in (out / "report.md").read_text() and digest in (out / "report.html").read_text()


def test_a_changed_imported_file_is_other_code_for_resume(lab_agent, tmp_path):
    out = tmp_path / "run"
    argv = ["--import", str(lab_agent), "--agents", "lab_random", "--tasks", "Grasp", "--seeds", "1", "--no-video"]
    assert evaluate.main([*argv, "--out", str(out)]) == 0
    before = json.loads((out / "results.json").read_text())["provenance"]["commit"]
    lab_agent.write_text(LAB_AGENT + "\n# a change\n")
    from panda_grasp_env.agents.evaluation.protocol import code_label

    assert code_label([str(lab_agent)]) != before


def test_help_lists_what_an_import_registered(lab_agent, capsys):
    with pytest.raises(SystemExit):
        evaluate.parse_args(["--import", str(lab_agent), "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert f"Registered by --import {lab_agent}: tasks []; agents ['lab_random']" in text


@pytest.mark.unit
@pytest.mark.parametrize("name", ["random", "tower_build_dqn", "", "two words"])
def test_an_agent_name_that_is_built_in_shipped_or_not_a_name_is_refused(name):
    with pytest.raises(ValueError, match="register_agent"):
        registry.register_agent(name, "Grasp")


@pytest.mark.unit
def test_the_workspace_bounds_have_public_names():
    workspace, spawn = panda_grasp_env.WORKSPACE, panda_grasp_env.SPAWN_REGION
    assert workspace.shape == (3, 2) and spawn.shape == (2, 2)
    assert np.all(workspace[:2, 0] <= spawn[:, 0]) and np.all(spawn[:, 1] <= workspace[:2, 1])
