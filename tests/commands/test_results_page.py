"""What a person sees of an evaluate.py run: report.html (in a real browser too), the PNGs, the terminal, and a
reason for every failed episode."""

import json
import re
import shutil

import pytest
from testkit import ROOT

from panda_grasp_env.agents.evaluation.episodes import episode_failure
from panda_grasp_env.commands import evaluate, results_figures, results_page

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
#: The flags headless Chromium runs with in containers (no sandbox, no GPU, nothing fetched in the background).
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """A small real run (random and the oracle on the two tower-breaking tasks, two seeds, the planned agent's
    tasks skipped) with one video, and what it printed."""
    import contextlib
    import io

    out = tmp_path_factory.mktemp("run")
    printed = io.StringIO()
    argv = [
        "--agents",
        "random,oracle,expert",
        "--tasks",
        "TowerBreak,TowerBreakDirectional",
        "--seeds",
        "2",
        "--no-video",
        "--out",
        str(out),
    ]
    with contextlib.redirect_stdout(printed):
        assert evaluate.main(argv) == 0
    # one clip, as the videos step writes them (a run with videos renders 4 of them: minutes)
    from panda_grasp_env.agents.evaluation.episodes import close_kept_env, run_episode
    from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec

    (out / "videos").mkdir()
    run_episode(EpisodeSpec("oracle", "TowerBreak", 0), video=out / "videos" / "oracle_TowerBreak.mp4")
    close_kept_env()
    results_page.write_page(out)
    return out, printed.getvalue()


def test_the_page_holds_every_part_and_needs_nothing_outside_it(run):
    out, _ = run
    page = (out / "report.html").read_text()
    cells = re.findall(r"<td class='cell' data-agent='([^']+)' data-task='([^']+)'", page)
    assert sorted(cells) == sorted(
        (a, t) for a in ("random", "oracle") for t in ("TowerBreak", "TowerBreakDirectional")
    )
    assert page.count("<td class='absent'") >= 2  # expert does not apply to the tower tasks: greyed, with why
    assert "skipped: no scripted low-level expert is written for TowerBreak" in page
    for part in ("Trial success per task", "Failures", "Decision time", "Clips", "Protocol", "commit", "machine"):
        assert part in page
    assert "<a href='videos/oracle_TowerBreak.mp4'><img src='data:image/jpeg;base64," in page
    # self-contained: no script, nothing fetched (links to the videos beside it are the only references)
    assert "<script" not in page
    assert not re.findall(r"""(?:src|href)=['"](?!data:|videos/|#)""", page)


@pytest.mark.unit
def test_every_failed_episode_names_why(run):
    out, _ = run
    results = json.loads((out / "results.json").read_text())
    for key, m in results["metrics"].items():
        failed = m["episodes"] - m["trial_success"]["successes"]
        assert sum(m["episode_failures"].values()) == failed, key
        assert "unrecorded" not in m["episode_failures"]
    assert results["metrics"]["random/TowerBreakDirectional"]["episode_failures"]
    assert "episodes: " in (out / "report.md").read_text()


@pytest.mark.unit
def test_a_tower_toppled_the_wrong_way_is_a_failure_with_its_reason():
    """The oracle breaker told the opposite of the commanded direction: the tower falls, the wrong way."""
    import gymnasium as gym
    import numpy as np

    from panda_grasp_env.agents.evaluation.benchmarks import BENCHMARKS
    from panda_grasp_env.agents.evaluation.episodes import play_episode
    from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec
    from panda_grasp_env.agents.policies.towers import OracleBlocks, TowerBreakerAgent

    class Contrary(TowerBreakerAgent):
        def act(self, observation, info):  # +x <-> -x, +y <-> -y
            return super().act({**observation, "command": np.roll(observation["command"], 2)}, info)

    benchmark = BENCHMARKS["TowerBreakDirectional"]
    with gym.make(f"panda_grasp_env:{benchmark.env_id}", **benchmark.options) as env:
        result = play_episode(env, Contrary(OracleBlocks(env)), EpisodeSpec("contrary", "TowerBreakDirectional", 0))
    assert not result["result"]["success"] and result["result"]["failure"] == "wrong_direction"
    assert result["result"]["failures"] == {}  # every primitive did what it reported: no failed action


@pytest.mark.unit
def test_episode_failure_names_each_way_to_fail():
    fell_wrong = {"wrong_direction": True, "broken_by_failure": False, "physics_error": False}
    assert episode_failure(False, True, False, fell_wrong, out_of_steps=False) == "wrong_direction"
    assert episode_failure(True, True, False, {}, out_of_steps=False) is None
    assert episode_failure(False, False, True, {}, out_of_steps=True) == "step_limit"
    assert episode_failure(False, False, True, {}, out_of_steps=False) == "gave_up"
    assert episode_failure(False, True, False, {"physics_error": True}, out_of_steps=False) == "physics_error"


@pytest.mark.unit
def test_the_terminal_opens_with_a_count_of_skipped_pairs(run):
    _, printed = run
    lines = printed.splitlines()
    skipped = [line for line in lines if line.startswith("skipped")]
    assert skipped == [f"skipped 2 agent/task pairs that do not apply (which and why: {run[0] / 'report.html'})"]
    assert max(map(len, lines)) < 250


@pytest.mark.unit
def test_pngs_label_every_bar_and_keep_the_legend_off_the_data(run):
    out, _ = run
    table = json.loads((out / "results.json").read_text())["metrics"]
    figure = results_figures.success_figure(table)
    assert [t.get_text() for t in figure.legends[0].get_texts()] == ["scripted", "random"]
    legend = figure.legends[0].get_window_extent()
    axes = [a for a in figure.axes if a.get_visible()]
    assert [a.get_title(loc="left") for a in axes] == ["TowerBreak", "TowerBreakDirectional"]
    assert all(not legend.overlaps(a.get_window_extent()) for a in axes)
    assert [t.get_text() for t in axes[0].get_yticklabels()] == ["oracle", "random"]  # scripted before random
    colours = {p.get_facecolor()[:3] for p in axes[0].patches}
    assert len(colours) == 2  # one colour per family
    import matplotlib.pyplot as plt

    plt.close(figure)
    from PIL import Image

    width, _ = Image.open(out / "failures.png").size
    assert width < 2000


def test_the_page_renders_in_a_real_browser(run, tmp_path):
    if CHROMIUM is None:
        pytest.skip("needs Chromium: apt-get install chromium (Debian), as .ci/run does; then pip install playwright")
    playwright = pytest.importorskip("playwright.sync_api", reason="needs playwright: pip install -e '.[test]'")
    out, _ = run
    errors = []
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch_persistent_context(
            str(tmp_path / "profile"), executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS
        )
        try:
            page = browser.new_page()
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto((out / "report.html").as_uri())
            page.wait_for_load_state("load")
            cells = page.locator("table.heatmap:not(.decisions) td.cell")
            assert cells.count() == 4
            assert all(cells.nth(i).is_visible() for i in range(4))
            assert page.locator("section svg").count() >= 2
            shot = page.screenshot(full_page=True)
        finally:
            browser.close()
    assert errors == []
    import io

    import numpy as np
    from PIL import Image

    pixels = np.asarray(Image.open(io.BytesIO(shot)).convert("RGB"), dtype=float)
    assert pixels.shape[0] > 600 and pixels.std() > 20  # not blank: text, shaded cells and charts
    assert len(np.unique(pixels.reshape(-1, 3)[::97], axis=0)) > 50


@pytest.mark.unit
def test_a_run_compared_with_itself_shows_no_change(run, capsys):
    out, _ = run
    assert evaluate.main(["compare", str(out), str(out), "--out", str(out / "self.html")]) == 0
    assert "0 better, 0 worse, 4 no detectable change" in capsys.readouterr().out


@pytest.mark.unit
def test_the_heatmap_of_published_tables(tmp_path):
    cells = {("planned", "Grasp"): {"rate": 1.0, "successes": 10, "n": 10, "ci95": [0.72, 1.0]}}
    html = results_page.heatmap_html(cells, ["Grasp", "Lift"])
    assert html.count("<td class='cell'") == 1 and html.count("<td class='absent'") == 1
    assert "100 %<small>72–100 · n 10</small>" in html


@pytest.mark.unit
def test_the_results_page_reads_the_published_quick_table():
    text = (ROOT / "docs" / "benchmark.md").read_text()
    cells = results_page.published_cells(text)
    assert cells[("stack_bc", "Stack")] == {"rate": 0.05, "successes": 1, "n": 20, "ci95": [0.0089, 0.2361]}
    assert cells[("grasp_clutter_dqn", "GraspAdversarial")]["successes"] == 2  # "**name** (learned)" read as name
    assert len(cells) == sum(
        1 for line in text.splitlines() if re.match(r"\| (\*\*)?\w+(\*\* \(learned\))? \| \w+ \| \d", line)
    )
    with pytest.raises(ValueError, match="no results table"):
        results_page.published_cells("# nothing here")
