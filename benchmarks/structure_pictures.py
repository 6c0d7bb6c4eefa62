"""Pictures of every named structure, as laid out exactly and after standing 5 s: the suite's docs page.

    python benchmarks/structure_pictures.py [--out docs/images/structures.png]

Each tile shows one structure of ``model.structure_suite`` standing in the workcell (its scaffold, if any,
propping it), seen from a camera aimed at it, captioned with its tier and name and how far its pieces moved in
5 simulated seconds.  Tiles run tier by tier, six to a row.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import mujoco
import numpy as np

from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.model.structure_suite import SUITE
from panda_grasp_env.model.structures import TIERS, structure_scene
from panda_grasp_env.sim.rendering import CameraRenderer
from panda_grasp_env.sim.structure_layout import stand_pieces
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tooling.runs import atomic_path
from panda_grasp_env.tooling.video import write_lines

#: Where each structure stands (table point, metres) and its heading (radians).
ORIGIN, HEADING = (0.55, 0.0), 0.5
TILE, PER_ROW, STAND_TIME = (320, 240), 6, 5.0


def picture(name: str) -> np.ndarray:
    """One captioned tile of structure ``name`` after standing ``STAND_TIME``."""
    structure = SUITE[name]
    cell = Workcell(structure_scene(SceneConfig(), structure))
    cell.clear()
    pieces = list(structure.pieces + structure.scaffold) if structure.scaffold else list(structure.pieces)
    slots = cell.object_ids[: len(pieces)]
    stand_pieces(cell, structure, pieces, slots, ORIGIN, HEADING)
    laid = cell.data.xpos[slots].copy()
    cell.wait(STAND_TIME)
    moved = np.linalg.norm(cell.data.xpos[slots] - laid, axis=1).max()
    camera = mujoco.MjvCamera()
    camera.lookat[:] = [*ORIGIN, 0.14]
    # Looking across the structure's own x axis, from in front of it and a little to its side.
    camera.distance, camera.azimuth, camera.elevation = 0.9, np.degrees(HEADING) + 70.0, -20.0
    renderer = CameraRenderer(cell.model, *TILE, profile="pretty")
    frame = renderer.render(cell.data, camera).copy()
    tier = f"tier {structure.tier} ({TIERS[structure.tier - 1]})"
    write_lines(frame, [f"{name}: {tier}", f"moved {moved * 1000:.1f} mm in {STAND_TIME:.0f} s"])
    print(f"{name:22s} {tier:26s} pieces {len(structure.pieces)}, moved {moved * 1000:.2f} mm")
    return frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("docs/images/structures.png"))
    args = parser.parse_args()
    import imageio.v3 as iio

    tiles = [picture(name) for name in sorted(SUITE, key=lambda n: SUITE[n].tier)]
    blank = np.full_like(tiles[0], 255)
    tiles += [blank] * (-len(tiles) % PER_ROW)
    rows = [np.concatenate(tiles[i : i + PER_ROW], axis=1) for i in range(0, len(tiles), PER_ROW)]
    with atomic_path(args.out) as path:
        iio.imwrite(path, np.concatenate(rows, axis=0), extension=".png")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
