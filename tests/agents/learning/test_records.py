"""What a run leaves behind (``agents/learning/records.py``): the best policy and how it was chosen, and the
model card."""

import json
import shutil

import pytest

from panda_grasp_env.agents.learning.records import load_best_policy, save_best_policy
from panda_grasp_env.commands import train


def test_a_policy_chosen_on_selection_seeds_is_tested_and_carded_as_such(finished_run, tmp_path):
    run = tmp_path / finished_run.name
    shutil.copytree(finished_run, run)
    policy, _ = load_best_policy(run)
    with pytest.raises(ValueError, match="chosen_by='luck'"):
        save_best_policy(policy, run, 12, chosen_by="luck")
    save_best_policy(policy, run, 12, chosen_by="selection")
    assert train.main(["--retest", str(run)]) == 0
    final = json.loads((run / "final.json").read_text())
    assert final["chosen_by"] == "selection" and final["best_steps"] == 12
    assert "chosen over the best periodic validation's on selection seeds" in (run / "card.md").read_text()
