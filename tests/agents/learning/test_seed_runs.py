"""``train.py --seeds``: one config on several training seeds (local processes or Ray tasks), aggregated with
rliable, and the aggregate on a shipped checkpoint's card and in evaluate.py's report."""

import json

import numpy as np
import pytest
from testkit import CONFIGS, TINY_DQN

from panda_grasp_env.agents.evaluation.metrics import rate
from panda_grasp_env.agents.learning.config import load_config
from panda_grasp_env.agents.learning.seed_figures import aggregate_runs, study_html, study_markdown, study_summary
from panda_grasp_env.agents.learning.seed_runs import parse_seeds
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.commands import train

pytest.importorskip("rliable", reason="train.py --seeds needs rliable: pip install -e '.[seeds]'")

CONFIG = str(CONFIGS / "grasp_clutter_dqn.yaml")


def test_aggregates_are_rliables_with_stratified_bootstrap_intervals():
    scores = np.array([[0.6], [0.9], [0.95], [1.0]])  # 4 runs x 1 task
    figures = aggregate_runs(scores)
    iqm, low, high = figures["aggregates"]["iqm"]
    assert iqm == pytest.approx(0.925)  # the mean of the middle two runs
    assert 0.6 <= low <= iqm <= high <= 1.0
    assert figures["aggregates"]["mean"][0] == pytest.approx(0.8625)
    assert figures["aggregates"]["optimality_gap"][0] == pytest.approx(0.1375)
    profile = dict(zip(figures["profile"]["tau"], figures["profile"]["fraction"]))
    assert profile[0.5] == 1.0 and profile[0.7] == 0.75 and profile[0.92] == 0.5 and profile[1.0] == 0.0
    # The bootstrap is seeded whatever state numpy's global generator is in, and leaves that state alone.
    np.random.seed(12345)
    np.random.random(17)
    before = np.random.get_state()[1].copy()
    assert aggregate_runs(scores) == figures
    assert np.array_equal(np.random.get_state()[1], before)


@pytest.mark.unit
def test_a_structure_study_aggregates_each_tier_that_every_run_played():
    def final(tiers):  # tier -> (successes, episodes)
        by_tier = {t: rate(won, n) for t, (won, n) in tiers.items()}
        won, n = sum(w for w, _ in tiers.values()), sum(n for _, n in tiers.values())
        metrics = {"trial_success": rate(won, n), "action_efficiency": 0.1, "trial_success_by_tier": by_tier}
        return {"steps": 10, "wall_seconds": 60.0, "test_seeds": [1, 4], "metrics": metrics}

    outcomes = [
        {"seed": 0, "run_dir": "a", "final": final({"1": (1, 2), "2": (2, 2)})},
        {"seed": 1, "run_dir": "b", "final": final({"1": (0, 2), "3": (1, 1)})},
    ]
    study = study_summary(load_config(CONFIGS / "structure_builder_dqn.yaml"), outcomes)
    assert set(study["metrics"]) == {"trial_success", "action_efficiency", "trial_success_tier_1"}
    assert study["metrics"]["trial_success_tier_1"]["aggregates"]["mean"][0] == pytest.approx(0.25)
    assert [run["trial_success_tier_1"]["successes"] for run in study["runs"]] == [1, 0]
    assert "| trial success tier 1 | 25.0 % " in study_markdown(study)


@pytest.mark.unit
@pytest.mark.parametrize("bad", ["0", "0,0", "a,b", "-1,2"])
def test_bad_seed_lists_are_refused(bad):
    with pytest.raises(ValueError, match="--seeds"):
        parse_seeds(bad)


@pytest.mark.unit
def test_seeds_go_with_a_config(capsys):
    with pytest.raises(SystemExit):
        train.main(["--retest", "x", "--seeds", "0,1"])
    assert "--seeds goes with --config" in capsys.readouterr().err


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A tiny config trained on seeds 0 and 1 in two local processes."""
    runs = tmp_path_factory.mktemp("runs")
    argv = ["--config", CONFIG, "--runs", str(runs), "--seeds", "0,1", "--workers", "2", *TINY_DQN]
    assert train.main(argv) == 0
    return runs


def test_each_seed_is_a_run_and_the_study_aggregates_them(study):
    folder = study / "grasp_clutter_dqn-seeds-0-1"
    summary = json.loads((folder / "study.json").read_text())
    assert summary["seeds"] == [0, 1] and [r["seed"] for r in summary["runs"]] == [0, 1]
    for seed, run in zip((0, 1), summary["runs"]):
        final = json.loads((study / f"grasp_clutter_dqn-seed{seed}" / "final.json").read_text())
        assert run["trial_success"] == final["metrics"]["trial_success"]
    assert set(summary["metrics"]) == {"trial_success", "action_efficiency"}
    assert "IQM (95 % CI)" in (folder / "study.md").read_text() and (folder / "profile.png").stat().st_size > 0
    assert "<svg" in study_html(summary) and "| 0 | 12 |" in study_markdown(summary)


def test_a_study_run_again_keeps_its_finished_runs(study, capsys):
    before = (study / "grasp_clutter_dqn-seed0" / "final.json").read_text()
    argv = ["--config", CONFIG, "--runs", str(study), "--seeds", "0,1", "--workers", "1", *TINY_DQN]
    assert train.main(argv) == 0
    assert (study / "grasp_clutter_dqn-seed0" / "final.json").read_text() == before
    assert not list(study.glob("grasp_clutter_dqn-seed0-*"))  # no second run folder


@pytest.mark.unit
def test_a_study_goes_onto_its_checkpoints_card_and_into_the_report(study, tmp_path, monkeypatch, capsys):
    from panda_grasp_env.commands import results_page

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    assert train.main(["--ship", str(study / "grasp_clutter_dqn-seed0"), "--name", "tiny"]) == 0
    assert train.main(["--ship", str(study / "grasp_clutter_dqn-seeds-0-1"), "--name", "tiny"]) == 0
    card = (tmp_path / "checkpoints" / "tiny" / "card.md").read_text()
    assert "## Over training seeds" in card and "![performance profile](seeds_profile.png)" in card
    assert "<h4>Over 2 training seeds (0, 1)</h4>" in results_page.seeds_section("tiny")
    # a study of another config is refused
    other = study / "other"
    other.mkdir()
    summary = json.loads((study / "grasp_clutter_dqn-seeds-0-1" / "study.json").read_text())
    summary["config"]["total_steps"] = 99
    (other / "study.json").write_text(json.dumps(summary))
    assert train.main(["--ship", str(other), "--name", "tiny"]) == 2
    assert "total_steps" in capsys.readouterr().err


@pytest.mark.slow  # a Ray cluster of two nodes starting: minutes on a loaded 2-core machine
def test_seeds_train_as_ray_tasks_on_a_cluster_of_a_head_and_a_worker(tmp_path):
    pytest.importorskip("ray")
    from ray.cluster_utils import Cluster

    cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    cluster.add_node(num_cpus=1)
    try:
        argv = ["--config", CONFIG, "--runs", str(tmp_path), "--seeds", "3,4", "--ray", cluster.address, *TINY_DQN]
        assert train.main(argv) == 0
    finally:
        cluster.shutdown()
    summary = json.loads((tmp_path / "grasp_clutter_dqn-seeds-3-4" / "study.json").read_text())
    assert [r["seed"] for r in summary["runs"]] == [3, 4]
    assert all((tmp_path / f"grasp_clutter_dqn-seed{s}" / "final.json").is_file() for s in (3, 4))
