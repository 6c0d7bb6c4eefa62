"""The main job: deterministic results, identical across workers, resumable."""

import json
import re

import pytest

from panda_grasp_env.agents.evaluation import runner
from panda_grasp_env.agents.evaluation.report import applicable
from panda_grasp_env.agents.learning.records import ship
from panda_grasp_env.agents.policies import learned
from panda_grasp_env.commands import evaluate

ARGS = ["--agents", "random,oracle", "--tasks", "TowerBreak", "--seeds", "2", "--no-video"]


def run(tmp_path, name, *extra):
    out = tmp_path / name
    assert evaluate.main([*ARGS, "--out", str(out), *extra]) == 0
    return out


def test_same_seeds_same_results_with_one_or_two_workers(tmp_path):
    first = run(tmp_path, "a")
    second = run(tmp_path, "b", "--workers", "2")
    assert (first / "results.json").read_text() == (second / "results.json").read_text()
    results = json.loads((first / "results.json").read_text())
    assert set(results["metrics"]) == {"oracle/TowerBreak", "random/TowerBreak"}
    assert results["metrics"]["oracle/TowerBreak"]["trial_success"]["successes"] == 2
    for name in ("results.csv", "report.md", "success.png", "failures.png", "timing.json"):
        assert (first / name).exists()


def test_resume_finishes_without_redoing_episodes(tmp_path):
    full = run(tmp_path, "full")
    partial = tmp_path / "partial"
    partial.mkdir()
    lines = (full / "episodes.jsonl").read_text().splitlines()
    (partial / "episodes.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:20])  # cut mid-line
    kept = [json.loads(line)["timing"] for line in lines[:2]]
    run(tmp_path, "partial", "--resume")
    resumed = [json.loads(line) for line in (partial / "episodes.jsonl").read_text().splitlines() if line.endswith("}")]
    assert [r["timing"] for r in resumed[:2]] == kept  # the finished episodes were not run again
    assert (partial / "results.json").read_text() == (full / "results.json").read_text()


def test_resume_runs_again_the_episodes_other_code_ran(tmp_path, capsys):
    full = run(tmp_path, "full")
    partial = tmp_path / "partial"
    partial.mkdir()
    records = [json.loads(line) for line in (full / "episodes.jsonl").read_text().splitlines()]
    records[0]["commit"] = "0000000"  # as if an earlier checkout had run it
    (partial / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records[:2]))
    run(tmp_path, "partial", "--resume")
    assert "1 episode(s) run by code other than" in capsys.readouterr().out
    set_aside = [json.loads(line) for line in (partial / "episodes.jsonl.prev").read_text().splitlines()]
    assert set_aside == [records[0]]  # kept aside, not lost
    resumed = [json.loads(line) for line in (partial / "episodes.jsonl").read_text().splitlines()]
    assert {r["commit"] for r in resumed} == {records[1]["commit"]}
    assert [r["timing"] for r in resumed if r["key"] == records[1]["key"]] == [records[1]["timing"]]  # kept
    assert [r["timing"] for r in resumed if r["key"] == records[0]["key"]] != [records[0]["timing"]]  # run again
    assert (partial / "results.json").read_text() == (full / "results.json").read_text()


def test_a_local_ray_instance_gives_the_same_results(tmp_path, monkeypatch):
    pytest.importorskip("ray")  # installed by the test extra; optional for users
    # "local" starts an instance even where Ray would join another: here an address nothing listens on (as a
    # cluster shut down earlier leaves in /tmp/ray/ray_current_cluster, which CI's second suite run joined)
    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:9")
    local = run(tmp_path, "local")
    on_ray = run(tmp_path, "ray", "--ray", "local")
    assert (local / "results.json").read_text() == (on_ray / "results.json").read_text()


@pytest.mark.unit
@pytest.mark.parametrize("bad", [["--agents", "genius"], ["--tasks", "Juggle"], ["--workers", "0"]])
def test_bad_arguments_exit_with_a_message(bad, capsys):
    with pytest.raises(SystemExit):
        evaluate.main(bad)
    assert "error" in capsys.readouterr().err


@pytest.mark.unit
def test_figures_that_do_not_apply_are_left_blank():
    none_attempted = {
        "grasp_success": {"rate": 0.0, "n": 0},
        "action_efficiency": 0.02,
        "cycles_per_sim_hour": 0.0,
        "collateral_per_action": 0.0,
    }
    assert set(applicable("Lift", none_attempted).values()) == {None}  # low-level: runs to the time limit
    grasped = {
        "grasp_success": {"rate": 0.9, "n": 10},
        "action_efficiency": 0.8,
        "cycles_per_sim_hour": 0.0,
        "collateral_per_action": 0.1,
    }
    assert applicable("GraspClutter", grasped) == {
        "grasp_success": 0.9,
        "action_efficiency": 0.8,
        "cycles_per_sim_hour": None,
        "collateral_per_action": 0.1,
    }
    assert applicable("BuildAndBreak", grasped)["cycles_per_sim_hour"] == 0.0


@pytest.mark.unit
def test_a_diverged_step_keeps_the_cycles_the_episode_completed():
    import gymnasium as gym
    import numpy as np

    from panda_grasp_env.agents.evaluation.episodes import play_episode
    from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
    from panda_grasp_env.agents.policies.random_agent import RandomAgent

    class CycleThenDiverge(gym.Wrapper):  # a cycle done from the first step; the physics diverges at the second
        def step(self, action):
            self.calls = getattr(self, "calls", 0) + 1
            if self.calls == 2:
                self.env.unwrapped.cell.data.qvel[:] = np.nan
            observation, reward, terminated, truncated, info = self.env.step(action)
            if not info["physics_error"]:
                info["cycles"] = 1
            return observation, reward, terminated, truncated, info

    env = CycleThenDiverge(gym.make("panda_grasp_env:PandaBuildAndBreak-v0"))
    result = play_episode(env, RandomAgent(env.action_space), EpisodeSpec("random", "BuildAndBreak", 0))["result"]
    assert result["physics_error"] and result["actions"] >= 2 and result["cycles"] == 1
    assert result["ideal_actions"] == env.unwrapped.task.ideal_actions
    env.close()


def test_a_fresh_run_keeps_the_previous_runs_episodes(tmp_path):
    first = (run(tmp_path, "out") / "episodes.jsonl").read_text()
    out = run(tmp_path, "out")  # again, without --resume
    assert (out / "episodes.jsonl.prev").read_text() == first
    assert len((out / "episodes.jsonl").read_text().splitlines()) == len(first.splitlines())


@pytest.mark.unit
def test_grasp_success_interval_widens_when_an_episodes_grasps_fail_together():
    from panda_grasp_env.agents.evaluation.metrics import clustered_rate, wilson

    spread = clustered_rate([3, 3, 3, 3], [4, 4, 4, 4])  # every episode 3 of 4: no sign of clustering
    assert spread["ci95"] == wilson(12, 16) and spread["design_effect"] == 1.0
    together = clustered_rate([4, 4, 4, 0], [4, 4, 4, 4])  # the same 12/16, all failures in one episode
    assert together["rate"] == spread["rate"] and together["design_effect"] > 2
    (low, high), (w_low, w_high) = together["ci95"], wilson(12, 16)
    assert low < w_low and high > w_high
    assert clustered_rate([5, 0], [5, 0])["ci95"] == wilson(5, 5)  # one episode with grasps: nothing to cluster


@pytest.mark.unit
def test_random_agent_does_not_replay_the_scene_draws():
    # Seeded with the episode's seed, a bare action space drew the same uniforms as the env's scene generator
    # (its pushes started where the tower was placed) until the scene drew from a spawned child stream.  The
    # agent's stream is its own either way.
    import gymnasium as gym
    import numpy as np

    from panda_grasp_env.agents.policies.random_agent import RandomAgent

    env = gym.make("panda_grasp_env:PandaTowerBreak-v0")
    towers, bare, agent_actions = [], [], []
    for seed in range(20):
        observation, info = env.reset(seed=seed)
        towers.append(env.unwrapped.cell.block_positions()[0, 0])
        env.action_space.seed(seed)
        bare.append(env.action_space.sample()[0])
        agent = RandomAgent(env.action_space, seed=seed)
        agent.reset(observation, info)
        first = agent.act(observation, info)
        agent.reset(observation, info)
        assert np.array_equal(agent.act(observation, info), first)  # still seeded: same seed, same actions
        agent_actions.append(first[0])
    env.close()
    assert abs(np.corrcoef(towers, bare)[0, 1]) < 0.5  # the trap this guarded against is gone
    assert abs(np.corrcoef(towers, agent_actions)[0, 1]) < 0.5


def test_any_seeds_and_task_options(tmp_path):
    # A held-out protocol without a hand-written loop: explicit seeds and env/task options on every task.
    out = tmp_path / "listed"
    argv = [
        "--agents",
        "oracle",
        "--tasks",
        "GraspClutter",
        "--seed-list",
        "5000,5002",
        "--task-options",
        "n_objects=3",
        "--no-video",
        "--out",
        str(out),
    ]
    assert evaluate.main(argv) == 0
    results = json.loads((out / "results.json").read_text())
    assert results["protocol"]["seeds"] == {"GraspClutter": [5000, 5002]}
    assert results["protocol"]["task_options"] == {"n_objects": 3}
    episodes = results["episodes"]
    assert [e["spec"]["seed"] for e in episodes] == [5000, 5002]
    assert all(e["spec"]["options"] == [["n_objects", 3]] for e in episodes)
    assert all(e["actions"] <= 3 * 3 for e in episodes)  # three objects to clear, not the default ten
    assert "5000,5002" in (out / "report.md").read_text()
    # --seed-start shifts the default count of seeds.
    protocol = evaluate.parse_args(["--tasks", "TowerBreak", "--seed-start", "7", "--seeds", "2"]).protocol
    assert protocol.seeds_of("TowerBreak") == [7, 8]


@pytest.mark.unit
@pytest.mark.parametrize(
    "bad, message",
    [
        (["--seed-list", "1,2", "--seeds", "3"], "--seed-list replaces --seeds"),
        (["--seed-list", "1,x"], "comma-separated integers"),
        (["--seed-list", "1,1"], "distinct seeds"),
        (["--task-options", "n_objects"], "is not KEY=VALUE"),
        (["--tasks", "GraspClutter", "--task-options", "n_objectz=3"], "n_objectz"),
    ],
)
def test_bad_protocol_arguments_name_the_culprit(bad, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        evaluate.parse_args(bad)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_a_protocol_file_reproduces_the_command_line_run(tmp_path):
    flags = [
        "--agents",
        "oracle",
        "--tasks",
        "GraspClutter",
        "--seed-list",
        "5000,5002",
        "--task-options",
        "n_objects=3",
        "--no-video",
    ]
    assert evaluate.main([*flags, "--out", str(tmp_path / "flags")]) == 0
    protocol = tmp_path / "protocol.yaml"
    protocol.write_text(
        "agents: [oracle]\ntasks: [GraspClutter]\nseed_list: [5000, 5002]\ntask_options: {n_objects: 3}\n"
    )
    assert evaluate.main(["--config", str(protocol), "--no-video", "--out", str(tmp_path / "file")]) == 0
    assert (tmp_path / "file" / "results.json").read_bytes() == (tmp_path / "flags" / "results.json").read_bytes()
    protocol.write_text("agents: [oracle]\nseed: [1]\n")
    with pytest.raises(SystemExit):
        evaluate.main(["--config", str(protocol)])


@pytest.mark.parametrize("protocol", [[], ["--full"]])
def test_the_default_protocols_cover_every_registered_benchmark(protocol):
    """``python evaluate.py`` plays every registered benchmark but those registered to be played when named
    (the mesh benchmarks, which need the objects extra, the towers of 6 and 8 blocks, and the structure
    benchmarks but their sample), with the seeds their
    registration gives (a task missing from a hand-kept table once made the main job fail)."""
    from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS, TALL_TOWERS, default_benchmarks

    chosen = evaluate.parse_args(protocol).protocol
    specs, _ = chosen.episode_specs()
    named_only = {
        t
        for t in BENCHMARKS
        if t.startswith(("GraspMesh", "Structure"))
        and t != "StructuresSample"
        or t.endswith(tuple(map(str, TALL_TOWERS)))
    }
    assert named_only and set(chosen.tasks) == set(BENCHMARKS) - named_only == set(default_benchmarks())
    assert set(chosen.tasks) == {spec.task for spec in specs}
    for task in default_benchmarks():
        expected = BENCHMARKS[task].seeds(full=bool(protocol))
        assert {spec.seed for spec in specs if spec.task == task and spec.agent == "random"} == set(range(expected))


@pytest.mark.unit
def test_a_heightmap_policy_plays_the_other_scenes_of_its_task():
    """push_grasp_dqn (trained on packed layouts) plays VPG's random heaps, in the heap env with its own spaces;
    a policy that cannot see or act in another scene of its task is skipped with the reason."""
    import inspect

    from panda_grasp_env.agents.evaluation.protocol import learned_env, skip_reason
    from panda_grasp_env.agents.policies.learned import Checkpoint
    from panda_grasp_env.env import PandaEnv
    from panda_grasp_env.env_options import AGENT_OPTIONS

    assert AGENT_OPTIONS <= set(inspect.signature(PandaEnv.__init__).parameters)

    assert skip_reason("push_grasp_dqn", "GraspClutter") is None
    assert skip_reason("grasp_clutter_dqn", "GraspAdversarial") is None
    assert "other level of action" in skip_reason("tower_build_dqn", "Stack")
    reason = skip_reason("tower_break_dqn", "TowerBreakDirectional")
    assert "expects observations (4, 112, 112), this env gives (6, 112, 112)" in reason  # the direction's channels
    assert "trained for Push" in skip_reason("push_sac_her", "Lift")
    checkpoint = Checkpoint("push_grasp_dqn")
    with checkpoint.make_env() as trained, learned_env(checkpoint, "GraspClutter") as heaps:
        assert heaps.spec.id == "PandaGraspClutter-v0" and heaps.spec.max_episode_steps == 60
        assert heaps.unwrapped.task.clutter and heaps.unwrapped.task.packed is None
        assert heaps.observation_space == trained.observation_space and heaps.action_space == trained.action_space


def _states(env, spec):
    """Hashes of every step's observation and simulator state while ``spec``'s agent plays ``spec.seed``."""
    import hashlib

    import numpy as np

    from panda_grasp_env.agents.evaluation.episodes import make_agent

    def digest(observation):
        parts = observation.values() if isinstance(observation, dict) else [observation]
        data = env.unwrapped.cell.data
        arrays = [*parts, data.qpos, data.qvel, data.qacc_warmstart]
        return hashlib.sha256(b"".join(np.ascontiguousarray(a).tobytes() for a in arrays)).hexdigest()

    agent = make_agent(spec, env)
    observation, info = env.reset(seed=spec.seed)
    agent.reset(observation, info)
    states = [digest(observation)]
    for _ in range(60):
        observation, _, terminated, truncated, info = env.step(agent.act(observation, info))
        states.append(digest(observation))
        if terminated or truncated:
            break
    return states


@pytest.mark.parametrize("agent,task", [("expert", "Push"), ("expert", "Stack"), ("oracle", "TowerBreak")])
def test_the_env_kept_from_the_last_episode_plays_the_episode_a_new_env_plays(agent, task):
    from panda_grasp_env.agents.evaluation.episodes import close_kept_env, episode_env, make_env, run_episode
    from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec

    later = EpisodeSpec(agent, task, 2)
    new_env = make_env(later)
    try:
        fresh = _states(new_env, later)
    finally:
        new_env.close()
    close_kept_env()
    try:
        run_episode(EpisodeSpec(agent, task, 1))  # the kept env plays another seed first
        kept = episode_env(later)
        assert _states(kept, later) == fresh
        assert episode_env(later) is kept
        run_episode(EpisodeSpec("random", task, 1))  # another agent gets an env of its own
        assert episode_env(later) is not kept
    finally:
        close_kept_env()


# --- bad input gets one clear line, before any episode runs -------------------------------------------


def refused(argv, capsys, monkeypatch):
    """``evaluate.main(argv)``'s exit code and error output; no episode may run."""
    monkeypatch.setattr(runner, "_run_job", lambda job: pytest.fail(f"episode {job[0].key} ran"))
    code = evaluate.main(argv)
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


@pytest.mark.unit
@pytest.mark.parametrize("where", ["a file", "below a file", "unwritable"])
def test_a_bad_out_is_one_error_line_before_any_episode(tmp_path, capsys, monkeypatch, where):
    (tmp_path / "file").write_text("x")
    out = {
        "a file": tmp_path / "file",
        "below a file": tmp_path / "file" / "out",
        "unwritable": "/sys/panda_grasp_env_out",
    }[where]  # fmt: skip (/sys refuses even root)
    code, err = refused([*ARGS, "--out", str(out)], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1 and err.startswith(f"error: --out {out}")
    assert {
        "a file": "is a file, not a folder",
        "below a file": "cannot write results there (Not a directory)",
        "unwritable": "cannot write results there",
    }[where] in err


@pytest.fixture(scope="module")
def finished_log(tmp_path_factory):
    out = tmp_path_factory.mktemp("finished")
    assert evaluate.main([*ARGS, "--out", str(out)]) == 0
    return (out / "episodes.jsonl").read_text().splitlines()


def tampered(records, change):
    record = json.loads(records[1])
    change(record)
    return json.dumps(record)


TAMPERINGS = {
    "not an object": (lambda lines: "[1, 2]", "line 2 is not an episode record"),
    "no key": (lambda lines: tampered(lines, lambda r: r.pop("key")), "line 2: keys .* are not key, commit"),
    "success a string": (
        lambda lines: tampered(lines, lambda r: r["result"].update(success="yes")),
        "line 2: result.success must be a JSON boolean, got 'yes'",
    ),
    "actions negative": (
        lambda lines: tampered(lines, lambda r: r["result"].update(actions=-3)),
        "line 2: result.actions must be a number >= 0",
    ),
    "an extra field": (
        lambda lines: tampered(lines, lambda r: r["result"].update(bonus=1)),
        "line 2: result must hold .*, and may hold",
    ),
    "an optional field of the wrong type": (
        lambda lines: tampered(lines, lambda r: r["result"].update(first_grasp="yes")),
        "line 2: result.first_grasp must be a JSON boolean",
    ),
    "key of another spec": (
        lambda lines: tampered(lines, lambda r: r.update(key=json.loads(lines[0])["key"])),
        "line 2: key .* is not the key of its spec",
    ),
    "another protocol's": (
        lambda lines: tampered(
            lines, lambda r: (r["result"]["spec"].update(seed=99), r.update(key=r["key"].replace("/1", "/99")))
        ),
        "line 2: episode random/TowerBreak/99 is not one of this protocol's",
    ),
    "a seed as a string": (  # its key is the int seed's, and it would sort against the others' ints
        lambda lines: tampered(lines, lambda r: r["result"]["spec"].update(seed=str(r["result"]["spec"]["seed"]))),
        "line 2: result.spec .* is not an episode's spec",
    ),
    "not JSON mid-file": (lambda lines: lines[1][:30], "line 2 is not valid JSON"),
    "bad timing": (
        lambda lines: tampered(lines, lambda r: r["timing"].update(wall_seconds="slow")),
        "line 2: timing must hold",
    ),
}


@pytest.mark.unit
@pytest.mark.parametrize("tampering", list(TAMPERINGS))
def test_resume_refuses_a_tampered_record_naming_its_line(tmp_path, capsys, monkeypatch, finished_log, tampering):
    change, message = TAMPERINGS[tampering]
    out = tmp_path / "out"
    out.mkdir()
    lines = [finished_log[0], change(finished_log), *finished_log[2:]]
    (out / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    code, err = refused([*ARGS, "--out", str(out), "--resume"], capsys, monkeypatch)
    assert code == 2 and err.count("\n") == 1
    assert re.search(f"error: {re.escape(str(out / 'episodes.jsonl'))} {message}", err), err
    assert not (out / "results.json").exists()


@pytest.mark.unit
def test_negative_seeds_get_the_projects_message(capsys):
    for argv in (["--seed-list", "-1,2"], ["--seed-list", "-5"]):
        with pytest.raises(SystemExit):
            evaluate.parse_args(argv)
        err = capsys.readouterr().err
        assert "--seed-list must hold distinct seeds >= 0" in err and "expected one argument" not in err


@pytest.mark.unit
def test_a_billion_seeds_is_refused_before_any_spec_is_made(capsys):
    for argv in (["--seeds", str(10**9)], ["--seed-list", ",".join(map(str, range(evaluate.MAX_SEEDS + 1)))]):
        with pytest.raises(SystemExit):
            evaluate.parse_args(argv)
        assert str(evaluate.MAX_SEEDS) in capsys.readouterr().err


@pytest.mark.unit
@pytest.mark.parametrize(
    ("code", "raised"),
    [
        ("raise RuntimeError('the lab server is down')", "RuntimeError: the lab server is down"),
        ("import sys\nsys.exit(3)", "SystemExit: 3"),  # else the program ended with status 3, saying nothing
    ],
)
def test_an_import_that_raises_is_one_error_line_naming_the_module(tmp_path, capsys, code, raised):
    broken = tmp_path / "broken_lab.py"
    broken.write_text(code + "\n")
    with pytest.raises(SystemExit) as exited:
        evaluate.parse_args(["--import", str(broken), "--tasks", "Grasp", "--seeds", "1"])
    err = capsys.readouterr().err
    assert exited.value.code == 2 and "Traceback" not in err
    assert f"--import {broken}: {raised}" in err.splitlines()[-1]


def test_evaluate_runs_a_shipped_checkpoint_by_name_and_skips_other_tasks(finished_run, tmp_path, monkeypatch):
    from panda_grasp_env.commands import evaluate

    monkeypatch.setattr(learned, "CHECKPOINTS", tmp_path / "checkpoints")
    ship(finished_run, "tiny")
    out = tmp_path / "results"
    args = ["--agents", "tiny,random", "--tasks", "Grasp,Push", "--seeds", "1", "--no-video", "--out", str(out)]
    assert evaluate.main(args) == 0
    results = json.loads((out / "results.json").read_text())
    assert set(results["metrics"]) == {"tiny/Grasp", "random/Grasp", "random/Push"}
    report = (out / "report.md").read_text()
    assert "skipped tiny/Push: checkpoint tiny was trained for Grasp" in report
    assert (out / "curve_tiny.png").exists()
    with pytest.raises(SystemExit):
        evaluate.main(["--agents", "nope", "--out", str(out)])


def test_a_users_structure_in_a_protocol_file_is_built_by_the_lookahead_planner(tmp_path):
    """docs/examples/gate_protocol.yaml: a structure defined outside the package, built through evaluate.py."""
    from pathlib import Path

    protocol = Path(__file__).resolve().parents[3] / "docs" / "examples" / "gate_protocol.yaml"
    flags = ["--config", str(protocol), "--agents", "planned_lookahead", "--seeds", "1", "--no-video"]
    assert evaluate.main([*flags, "--out", str(tmp_path)]) == 0
    (episode,) = json.loads((tmp_path / "results.json").read_text())["episodes"]
    assert episode["spec"]["task"] == "Structure" and episode["success"], episode
