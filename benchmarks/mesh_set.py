"""The procedural mesh set as the benchmark uses it: the split's figures, object previews, and per-object results.

    python benchmarks/mesh_set.py                          # split figures: objects, geoms, sizes, masses
    python benchmarks/mesh_set.py --previews docs/images   # a contact sheet of each split's evaluation objects
    python benchmarks/mesh_set.py --results results/run    # per-object first-grasp table of an evaluate.py run

Needs the objects extra.  ``--results`` reads an ``evaluate.py`` output folder's ``episodes.jsonl`` and prints,
per agent and benchmark task, the first-grasp successes over all episodes, the objects missed at least once
(with their successes / episodes; the GraspMesh benchmarks play each evaluation object once per 100 seeds),
and the objects never grasped first time.
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from panda_grasp_env.model.meshes import EVALUATION_OBJECTS, EXCLUDED, MAX_PARTS, SPLITS, load_mesh_object


def split_figures() -> None:
    """Per split: objects, geoms per object, merged objects, bounding-box sizes (cm) and volumes (cm^3)."""
    print(f"left out: {EXCLUDED}")
    print(
        f"{'split':6s} {'objects':>7s} {'geoms (median, max)':>20s} {'merged':>6s} "
        f"{'box cm (5 / 50 / 95 %)':>40s} {'volume cm3 (5 / 50 / 95 %)':>27s}"
    )
    for name, ids in SPLITS.items():
        objects = [load_mesh_object(i) for i in ids]
        geoms = [len(o.parts) for o in objects]
        merged = sum(1 for o in objects if len(o.parts) == MAX_PARTS)
        boxes = np.sort(np.array([o.half_extents * 200 for o in objects]), axis=1)
        quantiles = np.percentile(boxes, [5, 50, 95], axis=0)
        volumes = np.percentile([o.volume * 1e6 for o in objects], [5, 50, 95])
        box = " / ".join("x".join(f"{v:.1f}" for v in row) for row in quantiles)
        print(
            f"{name:6s} {len(ids):7d} {np.median(geoms):12.0f}, {max(geoms):5d} {merged:6d} {box:>40s} "
            f"{' / '.join(f'{v:.1f}' for v in volumes):>27s}"
        )


def previews(folder: Path, size: int = 96) -> None:
    """A 10 x 10 sheet per split of its evaluation objects, rendered alone on the table from above at 45 degrees,
    each labelled with its id: ``folder/mesh_objects_<split>.png``."""
    import cv2
    import imageio.v3 as iio
    import mujoco

    import panda_grasp_env  # noqa: F401  (it chooses MUJOCO_GL before mujoco is imported)
    from panda_grasp_env.model.objects import ObjectShape, apply_shape
    from panda_grasp_env.model.scene import SceneConfig
    from panda_grasp_env.sim.workcell import Workcell

    folder.mkdir(parents=True, exist_ok=True)
    for split, ids in EVALUATION_OBJECTS.items():
        cell = Workcell(SceneConfig(n_blocks=0, n_objects=1, mesh_objects=tuple(ids)))
        renderer = mujoco.Renderer(cell.model, size, size)
        camera = mujoco.MjvCamera()
        camera.lookat[:] = [0.5, 0.0, 0.03]
        camera.distance, camera.elevation, camera.azimuth = 0.2, -45.0, 135.0
        body = int(cell.object_ids[0])
        tiles = []
        for object_id in ids:
            mesh = load_mesh_object(object_id)
            shape = ObjectShape(
                "mesh",
                tuple(mesh.half_extents),
                (0.85, 0.45, 0.1),
                0.05,
                mesh=object_id,
                orientation=(1.0, 0.0, 0.0, 0.0),
            )
            apply_shape(cell.model, body, shape)
            cell.refresh_constants()
            cell.set_body_pose(body, [0.5, 0.0, shape.resting_half_height])
            mujoco.mj_forward(cell.model, cell.data)
            renderer.update_scene(cell.data, camera)
            tile = np.ascontiguousarray(renderer.render())
            cv2.putText(tile, str(object_id), (3, 12), cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1)
            tiles.append(tile)
        rows = [np.concatenate(tiles[r : r + 10], axis=1) for r in range(0, len(tiles), 10)]
        path = folder / f"mesh_objects_{split}.png"
        partial = path.with_suffix(".png.part")
        iio.imwrite(partial, np.concatenate(rows, axis=0), extension=".png")
        partial.replace(path)
        renderer.close()
        print(f"wrote {path}")


def per_object(results: Path) -> None:
    """First-grasp successes per mesh object, per agent and task, from ``results/episodes.jsonl``."""
    table: dict[tuple[str, str], dict[int, list[bool]]] = defaultdict(lambda: defaultdict(list))
    for line in (results / "episodes.jsonl").read_text().splitlines():
        result = json.loads(line)["result"]
        if len(result.get("meshes", ())) == 1 and "first_grasp" in result:
            key = (result["spec"]["agent"], result["spec"]["task"])
            table[key][result["meshes"][0]].append(result["first_grasp"])
    if not table:
        raise SystemExit(f"no single-mesh grasping episodes in {results / 'episodes.jsonl'}")
    for (agent, task), objects in sorted(table.items()):
        print(f"\n{agent} on {task}: object id: first-grasp successes / episodes")
        successes = sum(sum(v) for v in objects.values())
        episodes = sum(len(v) for v in objects.values())
        print(f"  {successes}/{episodes} episodes over {len(objects)} objects")
        below = [f"{i}: {sum(v)}/{len(v)}" for i, v in sorted(objects.items()) if sum(v) < len(v)]
        shown = ", ".join(below[:20]) + (", ..." if len(below) > 20 else "")
        print(f"  objects missed at least once ({len(below)}): {shown or 'none'}")
        never = [i for i, v in sorted(objects.items()) if not any(v)]
        print(
            f"  never grasped first time ({len(never)}): {never if len(never) <= 20 else f'{len(never)} of {len(objects)}'}"
        )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--previews", type=Path, help="write contact sheets of the evaluation objects here")
    parser.add_argument("--results", type=Path, help="an evaluate.py output folder: per-object table")
    args = parser.parse_args()
    if args.results is not None:
        per_object(args.results)
    elif args.previews is not None:
        previews(args.previews)
    else:
        split_figures()


if __name__ == "__main__":
    main()
