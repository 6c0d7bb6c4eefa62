"""Does the goal-conditioned builder rank its teacher's actions first?  Scores a ``goal_heightmap_dqn`` run's
network (``latest.zip``) on the teacher's paid steps, found in the run's replay buffer (``taught_rows``): the
first ``1 - held_out`` of them as the learner saw them in training, the rest held out by this script only.
For each step it compares the greedy action over every allowed cell and heading with the demonstrated one.

    python benchmarks/builder_imitation.py runs/<run> [--held-out 0.2] [--updates 0] [--learning-rate 1e-3]
        [--loss margin|cross_entropy] [--temperature 0.05] [--fresh]

Prints a JSON line per scoring: the share of steps whose greedy action has the demonstrated primitive; lies
within ``SAME_ACTION_RADIUS`` (12 mm) of the demonstrated cell; and also within one heading of it, counted
over a whole turn, modulo a half turn, modulo a quarter turn and (runs from commit 8dfa327 on) modulo the turn
after which that demonstration repeats.  With ``--updates N`` it then takes N supervised steps on the seen part
alone, scoring every ``--every``: ``--loss margin``, DQfD's large-margin loss (``large_margin_loss``), or
``--loss cross_entropy``, behaviour cloning on the Q-maps (``demonstration_cross_entropy`` at
``--temperature``): the learner's own ``LargeMarginMixin.supervised_loss``.  ``--fresh`` starts those steps from a newly initialised network (seeded by ``--seed``)
instead of the run's, as a run's pretraining does.  The run folder is only read.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import numpy as np
import torch

from panda_grasp_env.agents.learning.config import load_config, make_vec_env
from panda_grasp_env.agents.learning.goal_building import GoalHeightmapDQN
from panda_grasp_env.agents.learning.heightmap_imitation import IMITATION_LOSSES, SAME_ACTION_RADIUS


def within_one_heading(near: bool, turn: int, period: int) -> bool:
    """Near, and ``turn`` headings from the demonstrated heading, modulo ``period`` headings, is at most one."""
    turn %= period
    return near and min(turn, period - turn) <= 1


def imitation_scores(
    model: GoalHeightmapDQN, observations: np.ndarray, actions: np.ndarray, periods: list[int]
) -> dict:
    """Shares of the demonstrated steps (encoded heightmaps ``observations``, pixel ``actions``) whose greedy
    action matches them as the module doc says; ``periods`` per step in headings (empty: not recorded)."""
    q_net = model.q_net
    shape = (q_net.n_primitives, q_net.rotations, q_net.rows, q_net.cols)
    cell = model.policy.network_args["cell_size"]
    counts = {"primitive": 0, "near": 0, "heading": 0, "heading_half": 0, "heading_quarter": 0, "heading_repeat": 0}
    with torch.no_grad():
        for i, observation in enumerate(observations):
            batch = torch.as_tensor(observation[None])
            values = q_net(batch).masked_fill(~q_net.allowed(batch), -torch.inf)[0]
            chosen = np.unravel_index(int(values.argmax()), shape)
            shown = np.unravel_index(int(actions[i]), shape)
            near = (
                chosen[0] == shown[0]
                and cell * np.hypot(chosen[2] - shown[2], chosen[3] - shown[3]) <= SAME_ACTION_RADIUS
            )

            counts["primitive"] += int(chosen[0] == shown[0])
            counts["near"] += int(near)
            turn = int(chosen[1] - shown[1])
            counts["heading"] += within_one_heading(near, turn, q_net.rotations)
            counts["heading_half"] += within_one_heading(near, turn, max(1, q_net.rotations // 2))
            counts["heading_quarter"] += within_one_heading(near, turn, max(1, q_net.rotations // 4))
            counts["heading_repeat"] += within_one_heading(near, turn, periods[i]) if periods else 0
    scores = {name: round(count / len(observations), 3) for name, count in counts.items()}
    if not periods:
        del scores["heading_repeat"]
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path, help="a goal_heightmap_dqn run folder with latest.zip and replay.pkl")
    parser.add_argument("--held-out", type=float, default=0.2, help="the share of taught steps held out (the last)")
    parser.add_argument("--seen-sample", type=int, default=40, help="seen steps scored, evenly spaced")
    parser.add_argument("--updates", type=int, default=0, help="large-margin steps on the seen part")
    parser.add_argument("--learning-rate", type=float, default=1e-3)
    parser.add_argument("--every", type=int, default=200, help="updates between scorings")
    parser.add_argument("--loss", choices=IMITATION_LOSSES, default="margin")
    parser.add_argument("--temperature", type=float, default=0.05, help="--loss cross_entropy: Q-value units")
    parser.add_argument("--fresh", action="store_true", help="update a newly initialised network")
    parser.add_argument("--seed", type=int, default=0, help="--fresh: the initialisation's seed")
    args = parser.parse_args()
    if not 0 < args.held_out < 1:
        raise ValueError(f"--held-out must lie in (0, 1), got {args.held_out}")
    if not args.temperature > 0:
        raise ValueError(f"--temperature must be > 0, got {args.temperature}")
    torch.set_num_threads(1)
    config = load_config(args.run / "config.yaml")
    env = make_vec_env(config)
    model = GoalHeightmapDQN.load(args.run / "latest.zip", env=env)
    model.load_replay_buffer(args.run / "replay.pkl")
    rows = np.array(model.taught_rows)
    if not len(rows):
        raise ValueError(f"{args.run}: the run has no taught steps (teacher_episodes 0, or it never paid)")
    observations = model.replay_buffer.observations[rows, 0]
    actions = model.replay_buffer.actions[rows, 0, 0].astype(np.int64)
    periods = list(model.taught_periods) if len(model.taught_periods) == len(rows) else []
    cut = int(round((1 - args.held_out) * len(rows)))
    seen = np.linspace(0, cut - 1, min(args.seen_sample, cut)).astype(int)
    held = np.arange(cut, len(rows))

    def score(update: int, **extra: float) -> None:
        row = {
            "update": update,
            **extra,
            "held_out": imitation_scores(
                model, observations[held], actions[held], [periods[i] for i in held] if periods else []
            ),
            "seen": imitation_scores(
                model, observations[seen], actions[seen], [periods[i] for i in seen] if periods else []
            ),
        }
        print(json.dumps(row), flush=True)

    print(
        json.dumps(
            {"run": str(args.run), "steps": int(model.num_timesteps), "taught": len(rows), "held_out": len(held)}
        )
    )
    if args.fresh:
        torch.manual_seed(args.seed)
        for layer in model.q_net.modules():
            if hasattr(layer, "reset_parameters"):
                layer.reset_parameters()
    score(0)
    model.keep_taught(first=cut)
    optimiser = torch.optim.Adam(model.q_net.parameters(), lr=args.learning_rate)
    model.imitation_loss, model.temperature = args.loss, args.temperature
    losses, met = [], []
    for update in range(1, args.updates + 1):
        loss, share = model.supervised_loss(*model.margin_batch(model.batch_size))
        optimiser.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.q_net.parameters(), model.max_grad_norm)
        optimiser.step()
        losses.append(loss.item())
        met.append(share)
        if update % args.every == 0 or update == args.updates:
            score(update, loss=round(float(np.mean(losses)), 4), met=round(float(np.mean(met)), 3))
            losses, met = [], []


if __name__ == "__main__":
    main()
