"""Perception against the simulator's ground truth (loose bounds; the benchmark measures the figures)."""

import numpy as np
import pytest

from panda_grasp_env.geometry import yaw_quaternion
from panda_grasp_env.perception.camera import CameraModel
from panda_grasp_env.perception.heightmap import (
    HeightmapGrid,
    heightmap_from_points,
    heightmap_from_rgbd,
    heightmap_of_boxes,
)
from panda_grasp_env.perception.noise import DepthNoise, RGBNoise
from panda_grasp_env.perception.pose import (
    BlockPose,
    View,
    detect_towers,
    estimate_block_poses,
    estimate_block_poses_from_depth,
    follow_blocks,
    wrap_quarter,
)
from panda_grasp_env.perception.segmentation import colour_masks, fit_plane_ransac, foreground_mask
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.workcell import Workcell

pytestmark = pytest.mark.unit  # every test here is fast: the unit tier (python -m pytest -m unit)

SIZE = (320, 240)


@pytest.fixture(scope="module")
def scene():
    cell = Workcell()
    renderer = CameraRenderer(cell.model, *SIZE)
    yield cell, renderer
    renderer.close()


def views_of(cell, renderer, noise_seed=None, cameras=("overhead", "front")):
    views = []
    for camera in cameras:
        rgb, depth = renderer.render_rgbd(cell.data, camera)
        if noise_seed is not None:
            rng = np.random.default_rng(noise_seed)
            rgb, depth = RGBNoise().apply(rgb, rng), DepthNoise().apply(depth, rng)
        views.append(View(rgb, depth, CameraModel.from_mujoco(cell.model, cell.data, camera, *SIZE)))
    return views


def colours_of(cell):
    return dict(zip(cell.block_names, cell.config.colours.values()))


def test_camera_model_round_trip_and_block_centres_project_onto_their_blocks(scene):
    cell, renderer = scene
    cell.reset(np.random.default_rng(0), "scattered")
    view = views_of(cell, renderer, cameras=("overhead",))[0]
    points = view.camera.depth_to_world_points(view.depth)
    uv, _ = view.camera.world_to_pixel(points[100:103, 200:203])
    assert np.allclose(uv[..., 0], np.arange(200, 203)[None, :], atol=1e-6)
    assert np.allclose(uv[..., 1], np.arange(100, 103)[:, None], atol=1e-6)
    segmentation = renderer.render(cell.data, "overhead", "segmentation")
    (u, v), _ = view.camera.world_to_pixel(cell.block_positions()[0] + [0, 0, 0.025])  # top face centre
    assert segmentation[int(round(v)), int(round(u))] == cell.model.body_geomadr[cell.block_ids[0]]


def test_depth_noise_is_seeded_grows_with_distance_and_drops_edges():
    depth = np.full((60, 80), 0.5, dtype=np.float32)
    depth[:, 40:] = 1.5
    first = DepthNoise().apply(depth, np.random.default_rng(3))
    assert np.array_equal(first, DepthNoise().apply(depth, np.random.default_rng(3)), equal_nan=True)
    near, far = first[:, 5:35], first[:, 45:75]
    assert np.nanstd(far) > 2.5 * np.nanstd(near)  # sigma 3.5 mm at 1.5 m, 1.2 mm at 0.5 m
    assert np.isnan(first[:, 39:41]).mean() > 0.2  # the depth edge loses pixels


def test_colour_segmentation_matches_the_simulator(scene):
    cell, renderer = scene
    cell.reset(np.random.default_rng(1), "tower")
    for camera in ("overhead", "front"):
        rgb, _ = renderer.render_rgbd(cell.data, camera)
        truth = renderer.render(cell.data, camera, "segmentation")
        for name, mask in colour_masks(RGBNoise().apply(rgb, np.random.default_rng(0)), colours_of(cell)).items():
            true_mask = truth == cell.model.body_geomadr[cell.model.body(name).id]
            if true_mask.sum() > 200:  # skip slivers
                assert np.count_nonzero(mask & true_mask) / np.count_nonzero(mask | true_mask) > 0.9


def test_ransac_finds_the_table_and_the_objects_above_it(scene):
    cell, renderer = scene
    cell.reset(np.random.default_rng(2), "scattered")
    view = views_of(cell, renderer, noise_seed=1, cameras=("overhead",))[0]
    points = view.camera.depth_to_world_points(view.depth)
    plane, inliers = fit_plane_ransac(points.reshape(-1, 3), np.random.default_rng(0))
    assert plane.normal[2] > 0.999 and abs(plane.offset) < 0.002 and inliers.mean() > 0.5
    foreground = foreground_mask(points, plane)
    truth = renderer.render(cell.data, "overhead", "segmentation")
    blocks = np.isin(truth, [cell.model.body_geomadr[b] for b in cell.block_ids])
    assert np.count_nonzero(foreground & blocks) / np.count_nonzero(blocks) > 0.8  # edges drop out


@pytest.mark.parametrize("layout", ["scattered", "tower"])
def test_block_poses_within_a_few_millimetres_with_noise(scene, layout):
    cell, renderer = scene
    cell.reset(np.random.default_rng(5), layout)
    poses = estimate_block_poses(views_of(cell, renderer, noise_seed=5), colours_of(cell), cell.config.block_size)
    assert set(poses) == set(cell.block_names)
    for index, name in enumerate(cell.block_names):
        assert np.linalg.norm(poses[name].position - cell.block_positions()[index]) < 0.004
        assert abs(np.degrees(wrap_quarter(poses[name].yaw - cell.block_yaws()[index]))) < 3.0
    towers = detect_towers({n: p.position for n, p in poses.items()}, cell.config.block_size)
    if layout == "tower":
        assert towers == [[cell.block_names[i] for i in np.argsort(cell.block_positions()[:, 2])]]
    else:
        assert sorted(len(t) for t in towers) == [1, 1, 1, 1]


def colourless(views):
    """The views with every pixel black: nothing to read colour from."""
    return [View(np.zeros_like(v.rgb), v.depth, v.camera) for v in views]


def errors_to_true_blocks(cell, poses):
    """Per true block (in block order): the distance (mm) to the nearest estimate and the yaw error (degrees)
    of that estimate, modulo 90."""
    positions, yaws = cell.block_positions(), cell.block_yaws()
    result = []
    for position, yaw in zip(positions, yaws):
        nearest = min(poses, key=lambda p: np.linalg.norm(p.position - position))
        result.append(
            (1000 * np.linalg.norm(nearest.position - position), abs(np.degrees(wrap_quarter(nearest.yaw - yaw))))
        )
    return result


@pytest.mark.parametrize("layout", ["scattered", "tower"])
@pytest.mark.parametrize("seed", [6, 7])
def test_block_poses_from_depth_alone_within_a_few_millimetres(scene, layout, seed):
    cell, renderer = scene
    cell.reset(np.random.default_rng(seed), layout)
    poses = estimate_block_poses_from_depth(colourless(views_of(cell, renderer, noise_seed=seed)), 0.05)
    assert len(poses) == 4
    for distance_mm, yaw_deg in errors_to_true_blocks(cell, poses):
        assert distance_mm < 3.0 and yaw_deg < 2.0
    towers = detect_towers({p.name: p.position for p in poses}, cell.config.block_size)
    assert sorted(len(t) for t in towers) == ([4] if layout == "tower" else [1, 1, 1, 1])


@pytest.mark.parametrize(
    "layout",
    [
        # (x, y, level, yaw): two blocks side by side (one top face twice a block long), a tower of two
        # whose base touches a third block, and a twisted tower of three.
        [(0.50, 0.0, 0, 0.1), (0.50, 0.05, 0, 0.1), (0.40, -0.15, 0, 0.3), (0.62, -0.15, 0, -0.2)],
        [(0.50, 0.0, 0, 0.2), (0.51, 0.005, 1, -0.1), (0.50, 0.055, 0, 0.2), (0.40, -0.15, 0, 0.0)],
        [(0.50, 0.0, 0, 0.0), (0.50, 0.0, 1, 0.35), (0.50, 0.0, 2, -0.3), (0.40, 0.15, 0, 0.1)],
    ],
)
def test_block_poses_from_depth_tell_apart_blocks_that_touch(scene, layout):
    cell, renderer = scene
    cell.clear()
    for body, (x, y, level, yaw) in zip(cell.block_ids, layout):
        cell.set_body_pose(body, np.array([x, y, 0.025 + level * 0.0501]), yaw_quaternion(yaw))
    cell.settle(0.3)
    poses = estimate_block_poses_from_depth(colourless(views_of(cell, renderer, noise_seed=1)), 0.05)
    assert len(poses) == 4
    for distance_mm, yaw_deg in errors_to_true_blocks(cell, poses):
        assert distance_mm < 3.0 and yaw_deg < 2.0


@pytest.mark.parametrize("layout", ["scattered", "tower"])
def test_eight_blocks_are_told_apart_by_colour_and_by_depth(layout):
    """The eight default colours stay apart in colour segmentation (a lit face of a block clips no channel into
    a neighbour's hue window), and depth perception sees all eight levels of a 40 cm tower."""
    from panda_grasp_env.model.scene import SceneConfig

    cell = Workcell(SceneConfig(n_blocks=8))
    renderer = CameraRenderer(cell.model, *SIZE)
    cell.reset(np.random.default_rng(1), layout)
    views = views_of(cell, renderer, noise_seed=1)
    renderer.close()
    by_colour = estimate_block_poses(views, colours_of(cell), cell.config.block_size)
    assert set(by_colour) == set(cell.block_names)
    for index, name in enumerate(cell.block_names):
        assert np.linalg.norm(by_colour[name].position - cell.block_positions()[index]) < 0.004
    by_depth = estimate_block_poses_from_depth(colourless(views), cell.config.block_size)
    assert len(by_depth) == 8
    assert all(distance_mm < 3.0 for distance_mm, _ in errors_to_true_blocks(cell, by_depth))


def test_an_empty_table_has_no_blocks_by_depth(scene):
    cell, renderer = scene
    cell.clear()  # every block parked beside the table, the arm at home above it
    assert estimate_block_poses_from_depth(views_of(cell, renderer, noise_seed=0), 0.05) == []


def test_blocks_keep_the_names_of_the_known_blocks_they_lie_nearest():
    def seen(*positions):
        return [BlockPose(f"seen_{i}", np.array(p, dtype=float), 0.0, 100, 0.001) for i, p in enumerate(positions)]

    known = {"base": np.array([0.5, 0.0, 0.025]), "other": np.array([0.4, 0.1, 0.025])}
    # Listed in another order, each moved a little, and a block never seen before far from both.
    assert follow_blocks(known, seen((0.41, 0.1, 0.025), (0.7, -0.2, 0.025), (0.5, 0.01, 0.025))) == [
        "other",
        None,
        "base",
    ]
    # One known block unseen (in the hand): the seen one is named after the block it lies nearest.
    assert follow_blocks(known, seen((0.5, 0.0, 0.075))) == ["base"]
    assert follow_blocks({}, seen((0.5, 0.0, 0.025))) == [None]


def test_heightmap_sees_the_tower_top(scene):
    cell, renderer = scene
    cell.reset(np.random.default_rng(3), "tower")
    view = views_of(cell, renderer, cameras=("overhead",))[0]
    heights, colours = heightmap_from_rgbd(HeightmapGrid(resolution=0.004), view.camera, view.rgb, view.depth)
    assert heights.shape == (112, 112) and colours.shape == (112, 112, 3)
    assert abs(heights.max() - (cell.block_positions()[:, 2].max() + 0.025)) < 0.003


def test_no_visible_block_gives_an_empty_result(scene):
    cell, renderer = scene
    cell.reset(np.random.default_rng(0), "scattered")
    for body in cell.block_ids:
        cell.park(body)
    assert estimate_block_poses(views_of(cell, renderer), colours_of(cell), 0.05) == {}


@pytest.mark.parametrize(
    "rgb, depth, message",
    [
        (np.zeros((0, 0, 3), np.uint8), np.zeros((0, 0), np.float32), "shape"),
        (np.zeros((4, 4, 3), np.uint8), np.full((4, 4), np.nan, np.float32), "no finite pixel"),
        (np.zeros((4, 4), np.uint8), np.ones((4, 4), np.float32), "shape"),
        (np.zeros((4, 4, 3), np.float32), np.ones((4, 4), np.float32), "uint8"),
        (np.zeros((4, 4, 3), np.uint8), np.ones((4, 4), np.int32), "float"),
        (np.zeros((4, 4, 3), np.uint8), np.ones((5, 4), np.float32), "differ in size"),
    ],
)
def test_bad_images_raise(rgb, depth, message):
    camera = CameraModel(4, 4, np.eye(3), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match=message):
        estimate_block_poses([View(rgb, depth, camera)], {"red": (1.0, 0.0, 0.0)}, 0.05)


def test_bad_clouds_and_heightmap_images_raise():
    with pytest.raises(ValueError, match=r"points must have shape \(\.\.\., 3\)"):
        fit_plane_ransac(np.zeros((30, 2)), np.random.default_rng(0))
    camera = CameraModel(4, 4, np.eye(3), np.eye(3), np.zeros(3))
    with pytest.raises(ValueError, match="not the camera's image size"):
        heightmap_from_rgbd(HeightmapGrid(), camera, None, np.ones((5, 4), np.float32))
    with pytest.raises(ValueError, match="shape"):
        heightmap_from_rgbd(HeightmapGrid(), camera, np.zeros((4, 4, 4), np.uint8), np.ones((4, 4), np.float32))
    with pytest.raises(ValueError, match="one RGB triple per point"):
        heightmap_from_points(HeightmapGrid(), np.zeros((5, 3)), np.zeros((4, 3), np.uint8))


@pytest.mark.parametrize("shape", ["cube", "cylinder", "capsule"])
def test_top_grasp_candidate_picks_the_object_up(shape):
    import gymnasium as gym

    from panda_grasp_env.perception.grasps import detect_grasps_rgbd

    env = gym.make("panda_grasp_env:PandaGrasp-v0", shapes=(shape,), primitive_z=True)
    unwrapped = env.unwrapped
    env.reset(seed=4)
    _, depth = unwrapped.sensors.rgbd("overhead", 640, 480)
    candidates = detect_grasps_rgbd(depth, unwrapped.camera_model("overhead", 640, 480), np.random.default_rng(0))
    best = candidates[0]
    assert best.width <= 0.066 and np.allclose(best.rotation[:, 2], [0, 0, -1])
    assert all(a.score >= b.score for a, b in zip(candidates, candidates[1:]))
    info = env.step(unwrapped.actions.encode("grasp", best.position[0], best.position[1], best.yaw, best.position[2]))[
        4
    ]
    assert info["primitive_success"], info["primitive_reason"]
    env.close()


def test_grasp_detection_on_an_empty_table_returns_nothing(scene):
    from panda_grasp_env.perception.grasps import detect_grasps_rgbd

    cell, renderer = scene
    cell.reset(np.random.default_rng(0), "scattered")
    for body in cell.block_ids:
        cell.park(body)
    _, depth = renderer.render_rgbd(cell.data, "overhead")
    assert (
        detect_grasps_rgbd(
            depth, CameraModel.from_mujoco(cell.model, cell.data, "overhead", *SIZE), np.random.default_rng(0)
        )
        == []
    )


def test_a_filled_heightmap_hole_takes_its_highest_neighbours_height_and_colour():
    grid = HeightmapGrid(bounds=((0.0, 0.01), (0.0, 0.01), (0.0, 0.3)), resolution=0.002)
    points = np.array([[0.009, 0.009, 0.05], [0.005, 0.009, 0.04]])  # cells (0, 0) and (2, 0); (1, 0) is a hole
    heights, colours = heightmap_from_points(grid, points, np.array([[255, 0, 0], [0, 255, 0]], np.uint8))
    assert heights[1, 0] == pytest.approx(0.05)
    assert colours[1, 0].tolist() == [255, 0, 0]  # the red neighbour's colour, not a channel-wise max (yellow)


def test_boxes_draw_their_tops_on_the_heightmap_grid():
    grid = HeightmapGrid(((0.3, 0.7), (-0.2, 0.2), (0.0, 0.3)), 0.002)
    centres = np.array([[0.5, 0.0, 0.025], [0.5, 0.0, 0.075]])
    halves = np.array([[0.025, 0.025, 0.025], [0.07, 0.025, 0.025]])
    heights = heightmap_of_boxes(grid, centres, halves, np.array([0.0, np.pi / 2]))
    assert heights.max() == pytest.approx(0.1)
    # The plank turned a quarter: 5 cm along x, 14 cm along y.
    assert (heights > 0).sum() * 0.002**2 == pytest.approx(0.05 * 0.14, rel=0.05)
    row, col = (int(i) for i in grid.world_to_cell(np.array([0.5, 0.06])))
    assert heights[row, col] == pytest.approx(0.1)
    row, col = (int(i) for i in grid.world_to_cell(np.array([0.54, 0.0])))
    assert heights[row, col] == 0.0
