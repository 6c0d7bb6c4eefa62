"""``evaluate.py compare``: tested differences per (agent, task), corrected for their number; refusals."""

import json

import numpy as np
import pytest

from panda_grasp_env.commands import compare, evaluate

SEEDS = list(range(40))
#: (agent, task) -> per-episode success probability of the synthetic runs.
CELLS = {
    ("planned", "TowerBuild"): 0.9,
    ("oracle", "TowerBuild"): 0.95,
    ("tower_build_dqn", "TowerBuild"): 0.85,
    ("planned", "GraspClutter"): 0.7,
    ("random", "Lift"): 0.05,
}


def write_run(folder, draw_seed, weaken=None, seeds=SEEDS, versions=None):
    """A results folder as evaluate.py writes it, with episodes drawn at random from ``CELLS``' rates;
    ``weaken``: an (agent, task) whose success rate falls to 0.3 (and its actions, on failure, double)."""
    from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
    from panda_grasp_env.agents.evaluation.metrics import aggregate

    rng = np.random.default_rng(draw_seed)
    episodes = []
    for (agent, task), p in CELLS.items():
        p = 0.3 if (agent, task) == weaken else p
        for seed in seeds:
            success = bool(rng.random() < p)
            attempted = 4 if task != "Lift" else 0
            episodes.append(
                {
                    "spec": {"agent": agent, "task": task, "seed": seed, "options": []},
                    "success": success,
                    "completion": success,
                    "actions": 6 if success else 12,
                    "ideal_actions": 6,
                    "grasps_attempted": attempted,
                    "grasps_succeeded": attempted if success else int(rng.integers(0, 3)),
                    "cycles": 0,
                    "sim_seconds": 10.0,
                    "failures": {} if success else {"missed": 1},
                    "failure": None if success else "step_limit",
                    "physics_error": False,
                    "disturbed": 0,
                    "transit_contacts": 0,
                }
            )
    tasks = sorted({t for _, t in CELLS})
    results = {
        "protocol": {
            "agents": sorted({a for a, _ in CELLS}),
            "tasks": tasks,
            "full": False,
            "env_ids": {t: BENCHMARKS[t].env_id for t in tasks},
            "seeds": {t: list(seeds) for t in tasks},
            "task_options": {},
            "skipped": {},
        },
        "provenance": {"commit": "abc1234", "versions": versions or {"mujoco": "4.0.0"}, "machine": "test"},
        "metrics": aggregate(episodes),
        "episodes": episodes,
    }
    folder.mkdir()
    (folder / "results.json").write_text(json.dumps(results))
    return folder


def verdicts(capsys, *argv):
    assert evaluate.main(["compare", *map(str, argv)]) == 0
    return capsys.readouterr().out


def test_two_runs_of_one_protocol_show_no_detectable_change(tmp_path, capsys):
    a, b = write_run(tmp_path / "a", 1), write_run(tmp_path / "b", 2)  # other draws of the same rates
    out = verdicts(capsys, a, b)
    assert "5 (agent, task) cells" in out and "0 better, 0 worse, 5 no detectable change" in out
    page = (b / "compare.html").read_text()
    assert "no detectable change" in page and "class='worse'" not in page


def test_a_weakened_agent_is_worse_and_no_other(tmp_path, capsys):
    a, b = write_run(tmp_path / "a", 1), write_run(tmp_path / "b", 2, weaken=("tower_build_dqn", "TowerBuild"))
    out = verdicts(capsys, a, b, "--out", tmp_path / "c.html")
    assert "0 better, 1 worse, 4 no detectable change" in out
    changed = [line for line in out.splitlines() if line.startswith(("WORSE", "BETTER"))]
    assert changed and all(" tower_build_dqn/TowerBuild " in line for line in changed)
    assert any("trial_success" in line for line in changed)
    page = (tmp_path / "c.html").read_text()
    assert "class='worse'" in page
    assert page.count("data-verdict='worse'") == 1 and page.count("data-verdict='no detectable change'") == 4
    # the same two runs the other way round: better
    assert "1 better, 0 worse" in verdicts(capsys, b, a, "--out", tmp_path / "d.html")


@pytest.mark.unit
def test_mismatched_seeds_are_refused(tmp_path, capsys):
    a, b = write_run(tmp_path / "a", 1), write_run(tmp_path / "b", 1, seeds=range(100, 140))
    assert evaluate.main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert "different protocols" in err and "other seeds" in err and "0..39 (40)" in err
    assert not (b / "compare.html").exists()


def test_other_versions_are_warned_about_loudly(tmp_path, capsys):
    a = write_run(tmp_path / "a", 1)
    b = write_run(tmp_path / "b", 1, versions={"mujoco": "3.17.0"})
    assert evaluate.main(["compare", str(a), str(b)]) == 0
    captured = capsys.readouterr()
    assert "WARNING: other package versions" in captured.err and "mujoco 4.0.0 -> 3.17.0" in captured.err
    assert "mujoco 4.0.0 -&gt; 3.17.0" in (b / "compare.html").read_text()


@pytest.mark.unit
def test_a_folder_without_results_is_an_error(tmp_path, capsys):
    a = write_run(tmp_path / "a", 1)
    assert evaluate.main(["compare", str(a), str(tmp_path)]) == 2
    assert "not a finished evaluate.py results folder" in capsys.readouterr().err


@pytest.mark.unit
def test_corrections_and_tests():
    p = [0.01, 0.04, 0.03, 0.5]
    assert compare.adjust(p, "holm") == pytest.approx([0.04, 0.09, 0.09, 0.5])
    assert compare.adjust(p, "bh") == pytest.approx([0.04, 0.0533333, 0.0533333, 0.5])
    assert compare.fisher(10, 10, 10, 10) == 1.0 and compare.fisher(20, 20, 0, 20) < 1e-9
    # episodes that are all alike in both runs: no difference, p = 1
    in_a = np.array([True] * 5 + [False] * 5)
    assert compare.ratio_permutation(np.ones(10), np.full(10, 2.0), in_a) == 1.0
    # 5/5 grasps in each of run A's episodes, 0/5 in B's: the smallest p ten episodes can give
    numerators = np.array([5.0] * 5 + [0.0] * 5)
    assert compare.ratio_permutation(numerators, np.full(10, 5.0), in_a) < 0.02


def test_two_agents_of_one_run_are_compared_task_by_task(tmp_path, capsys):
    run = write_run(tmp_path / "a", 1, weaken=("planned", "TowerBuild"))
    out = verdicts(capsys, run, run, "--agents", "planned,oracle", "--out", tmp_path / "c.html")
    # planned (0.3) against oracle (0.95) on TowerBuild; GraspClutter has no oracle cell.
    assert "1 (agent, task) cells" in out and "1 better" in out
    assert any(line.startswith("BETTER") and "planned→oracle/TowerBuild" in line for line in out.splitlines())
    assert evaluate.main(["compare", str(run), str(run), "--agents", "planned,nobody"]) == 2
    assert "no episodes of agent 'nobody'" in capsys.readouterr().err
