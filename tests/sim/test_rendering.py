import numpy as np
import pytest

from panda_grasp_env.sim.rendering import CameraRenderer, RenderCache


@pytest.fixture(scope="module")
def tower_cell(cell):
    cell.reset(np.random.default_rng(0), "tower")
    return cell


@pytest.mark.unit
@pytest.mark.parametrize("camera", ["overhead", "front", "wrist"])
def test_every_camera_renders_all_modalities(tower_cell, camera):
    cache = RenderCache(tower_cell.model)
    try:
        rgb = cache.render(tower_cell.data, camera, 84, 84, "rgb")
        depth = cache.render(tower_cell.data, camera, 84, 84, "depth")
        segmentation = cache.render(tower_cell.data, camera, 84, 84, "segmentation")
    finally:
        cache.close()
    assert rgb.shape == (84, 84, 3) and rgb.dtype == np.uint8 and rgb.std() > 5
    assert depth.shape == (84, 84) and depth.dtype == np.float32 and np.isfinite(depth).all()
    assert segmentation.shape == (84, 84) and segmentation.dtype == np.int32


@pytest.mark.unit
def test_overhead_sees_the_blocks_with_metric_depth(tower_cell):
    with CameraRenderer(tower_cell.model, 640, 480, "fast") as renderer:
        segmentation = renderer.render(tower_cell.data, "overhead", "segmentation")
        depth = renderer.render(tower_cell.data, "overhead", "depth")
    top = int(np.argmax(tower_cell.block_positions()[:, 2]))
    top_geom = tower_cell.model.body_geomadr[tower_cell.block_ids[top]]
    mask = segmentation == top_geom
    assert mask.sum() > 200
    # Camera 1.05 m above the table; the top face of a 4-block tower is at 0.2 m.
    assert np.median(depth[mask]) == pytest.approx(1.05 - 0.2, abs=0.005)
    table = tower_cell.model.geom("table").id
    assert np.median(depth[segmentation == table]) == pytest.approx(1.05, abs=0.01)


@pytest.mark.unit
def test_fast_profile_draws_collision_geoms_pretty_draws_visual_meshes(tower_cell):
    with (
        CameraRenderer(tower_cell.model, 64, 48, "fast") as fast,
        CameraRenderer(tower_cell.model, 64, 48, "pretty") as pretty,
    ):
        seg_fast = fast.render(tower_cell.data, "front", "segmentation")
        seg_pretty = pretty.render(tower_cell.data, "front", "segmentation")
    groups = tower_cell.model.geom_group
    assert set(groups[np.unique(seg_fast[seg_fast >= 0])]) <= {0, 2}
    assert set(groups[np.unique(seg_pretty[seg_pretty >= 0])]) <= {0, 1}


@pytest.mark.unit
def test_bad_render_arguments(tower_cell):
    with pytest.raises(ValueError, match="profile"):
        CameraRenderer(tower_cell.model, 64, 64, "cinematic")
    with pytest.raises(ValueError, match="width"):
        CameraRenderer(tower_cell.model, 0, 64)
    with CameraRenderer(tower_cell.model, 32, 32) as renderer, pytest.raises(ValueError, match="modality"):
        renderer.render(tower_cell.data, "front", "infrared")


def test_closing_or_dropping_one_renderer_leaves_the_others_drawing(tower_cell):
    """Two envs in one process (training and validation): closing one, or dropping it unclosed, must not
    free the other's framebuffers (MuJoCo 3.x's Renderer.close frees them in whichever context is current)."""
    import gc

    with CameraRenderer(tower_cell.model, 48, 48) as kept:
        before = kept.render_rgbd(tower_cell.data, "overhead")
        closed, dropped = CameraRenderer(tower_cell.model, 48, 48), CameraRenderer(tower_cell.model, 48, 48)
        for other in (closed, dropped):
            other.render_rgbd(tower_cell.data, "overhead")
        kept.render_rgbd(tower_cell.data, "overhead")  # the kept one's context is now the current one
        closed.close()
        closed.close()  # idempotent
        del dropped
        gc.collect()
        after = kept.render_rgbd(tower_cell.data, "overhead")
        assert np.array_equal(before[0], after[0]) and np.array_equal(before[1], after[1])
        assert np.allclose(kept.render(tower_cell.data, "overhead", "depth"), before[1], atol=1e-3)  # metres


@pytest.mark.unit
@pytest.mark.parametrize("draw", ["render_rgbd", "segmentation"])
def test_a_renderer_dropped_unclosed_never_frees_its_context_inside_anothers_draw(tower_cell, monkeypatch, draw):
    """An env dropped without close() is cyclic garbage (its observers point back at it), and a collection can
    start at any allocation: here one starts right after the kept renderer made its context current, the
    worst moment.  Freeing the dropped renderer's context there garbled the draw (gymnasium's checker then
    found reset(seed=123) giving two different observations); it must wait until after."""
    import gc

    def frame(renderer):
        if draw == "render_rgbd":
            return np.concatenate(
                [a.ravel().astype(np.float64) for a in renderer.render_rgbd(tower_cell.data, "front")]
            )
        return renderer.render(tower_cell.data, "front", "segmentation")

    with CameraRenderer(tower_cell.model, 48, 48) as kept:
        before = frame(kept)
        context_class = type(kept._renderer._gl_context)
        make_current, armed = context_class.make_current, [False]

        def make_current_then_collect(context):
            make_current(context)
            if armed[0]:
                armed[0] = False
                assert gc.collect() > 0  # the dropped renderer's cycle is collected here

        monkeypatch.setattr(context_class, "make_current", make_current_then_collect)
        dropped = CameraRenderer(tower_cell.model, 48, 48)
        frame(dropped)
        dropped.cycle = dropped  # unreachable only as a cycle: freed by a collection, not at ``del``
        del dropped
        gc.disable()  # the collection comes where the test puts it, nowhere else
        try:
            armed[0] = True
            after = frame(kept)
        finally:
            gc.enable()
        assert not armed[0]  # the collection ran, inside the draw
        assert np.array_equal(before, after)


def test_a_script_that_leaves_an_episode_env_open_exits_cleanly():
    """MuJoCo's EGL module closes its display at exit; the open renderers are freed before that (the env an
    episode keeps for the next one was closed at exit after it, and failed on the closed display)."""
    import subprocess
    import sys

    script = (
        "from panda_grasp_env.agents.evaluation.episodes import run_episode\n"
        "from panda_grasp_env.agents.evaluation.protocol import EpisodeSpec\n"
        "run_episode(EpisodeSpec('grasp_clutter_dqn', 'Grasp', 0))\n"  # a heightmap policy: renderers
        "print('ran')\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "ran"
    assert "Error" not in done.stderr and "Traceback" not in done.stderr, done.stderr[-2000:]
