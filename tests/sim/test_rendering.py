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
