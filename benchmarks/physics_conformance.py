"""Physics conformance: the workcell's contacts measured against what rigid-body mechanics predicts.

    python benchmarks/physics_conformance.py [--force 100] [--stiff-contacts] [--json out.json]

Each row is one experiment on the env's own scene (``Workcell``, a 5 cm, 0.1 kg block on the table), printed
beside its analytic value:

* penetration under load: the block pressed down with ``--force`` newtons, and the same force pressing it
  sideways into the closed fingers (the robot's largest push force); rigid bodies: 0 mm; goal <= 1 mm;
* slide-versus-tip height: a frictionless horizontal force ramped slowly at height h on the block's back face
  slides it below h = w / (2 mu) and tips it above (w the block's width, mu the block-table friction);
* slip angle: gravity tilted slowly under a block of friction 0.5 (a cube tips only at 45 degrees):
  it slides from atan(mu);
* free fall: a block released 30 cm above the table meets it after sqrt(2 h / g);
* a settled tower: four blocks stacked and left 10 s: block k's centre at (k + 1/2) w, drift < 2 mm.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import panda_grasp_env  # noqa: E402, F401  (first: it chooses MUJOCO_GL before mujoco is imported)

# isort: split

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks._common import machine  # noqa: E402
from panda_grasp_env.geometry import yaw_quaternion  # noqa: E402
from panda_grasp_env.model.scene import SceneConfig  # noqa: E402
from panda_grasp_env.primitives.parameters import PrimitiveSettings  # noqa: E402
from panda_grasp_env.primitives.registry import Aim  # noqa: E402
from panda_grasp_env.primitives.top_down import push  # noqa: E402
from panda_grasp_env.sim.workcell import Workcell  # noqa: E402
from panda_grasp_env.tooling.runs import write_atomically  # noqa: E402

BLOCK_AT = np.array([0.5, 0.0])  # where the block stands (world x, y metres), clear of the robot at home
SETTINGS = PrimitiveSettings(primitives=("push",))
TILT_TIPPED = np.radians(3.0)  # a block turned this far has tipped
SLID = 0.003  # metres: a block that moved this far without tipping has slid


def fresh_block(cell: Workcell, friction: float | None = None) -> int:
    """The scene cleared, one block standing at ``BLOCK_AT`` at rest, with sliding ``friction`` (None: the scene's)."""
    cell.clear()
    block = int(cell.block_ids[0])
    cell.set_object_friction(block, friction)
    cell.set_body_pose(block, np.array([*BLOCK_AT, cell.config.block_size / 2]), yaw_quaternion(0.0))
    cell.settle(0.3)
    return block


def deepest_contact(cell: Workcell, body: int, others: set[int]) -> float:
    """Deepest penetration (metres, >= 0) between ``body``'s geoms and geoms of the bodies ``others`` now."""
    model, data, depth = cell.model, cell.data, 0.0
    for contact in data.contact[: data.ncon]:
        pair = {int(model.geom_bodyid[contact.geom1]), int(model.geom_bodyid[contact.geom2])}
        if body in pair and pair - {body} <= others and pair != {body}:
            depth = max(depth, -float(contact.dist))
    return depth


def penetration_into_table(cell: Workcell, force: float) -> float:
    block = fresh_block(cell)
    table_body = int(cell.model.geom_bodyid[cell.model.geom("table").id])
    cell.data.xfrc_applied[block, 2] = -force
    cell.wait(1.0)
    depth = deepest_contact(cell, block, {table_body})
    cell.data.xfrc_applied[block] = 0.0
    return depth


def watched_push(cell: Workcell, heading: float) -> tuple[float, float]:
    """One push of a fresh block from 6 cm behind it along ``heading`` at the automatic push height: (deepest
    penetration of the block into the fingers or the table, largest normal force on it from the fingers)."""
    block = fresh_block(cell)
    fingers = {int(body) for body in cell.robot.finger_bodies}
    table = int(cell.model.geom_bodyid[cell.model.geom("table").id])
    start = BLOCK_AT - 0.06 * np.array([np.cos(heading), np.sin(heading)])
    deepest, strongest = 0.0, 0.0

    def watch(cell: Workcell) -> None:
        nonlocal deepest, strongest
        deepest = max(deepest, deepest_contact(cell, block, fingers | {table}))
        wrench = np.zeros(6)
        for i, contact in enumerate(cell.data.contact[: cell.data.ncon]):
            pair = {int(cell.model.geom_bodyid[contact.geom1]), int(cell.model.geom_bodyid[contact.geom2])}
            if block in pair and pair & fingers:
                mujoco.mj_contactForce(cell.model, cell.data, i, wrench)
                strongest = max(strongest, float(wrench[0]))

    cell.physics.add_observer(watch)
    try:
        height = Aim("push", *start, heading).parameters(cell, SETTINGS).z
        push(cell, *start, height, heading, 0.15)
    finally:
        cell.physics.remove_observer(watch)
    return deepest, strongest


def penetration_while_pushed(cell: Workcell) -> tuple[float, float]:
    """(deepest penetration, largest finger force) over pushes from four headings (``watched_push``)."""
    figures = [watched_push(cell, heading) for heading in np.linspace(0.0, 2 * np.pi, 4, endpoint=False)]
    return max(depth for depth, _ in figures), max(force for _, force in figures)


def tips_when_pushed_at(cell: Workcell, height: float, ramp: float = 2.0) -> bool:
    """Whether a frictionless horizontal force ramped at ``ramp`` N/s, acting ``height`` metres above the table
    on the middle of the block's back face, tips the block (before sliding it ``SLID``)."""
    block = fresh_block(cell)
    half = cell.config.block_size / 2
    local_point = np.array([-half, 0.0, height - half])  # body frame: back face, ``height`` above the bottom
    start = cell.data.xpos[block].copy()
    step = cell.model.opt.timestep
    for i in range(int(3.0 / step)):
        force = np.array([ramp * i * step, 0.0, 0.0])
        point = cell.data.xpos[block] + cell.data.xmat[block].reshape(3, 3) @ local_point
        cell.data.qfrc_applied[:] = 0.0
        mujoco.mj_applyFT(cell.model, cell.data, force, np.zeros(3), point, block, cell.data.qfrc_applied)
        mujoco.mj_step(cell.model, cell.data)
        tilt = np.arccos(np.clip(cell.data.xmat[block][8], -1.0, 1.0))
        if tilt > TILT_TIPPED:
            break
        if np.linalg.norm(cell.data.xpos[block][:2] - start[:2]) > SLID:
            break
    cell.data.qfrc_applied[:] = 0.0
    return bool(tilt > TILT_TIPPED)


def threshold(happens_at: Callable[[float], bool], low: float, high: float, iterations: int = 9) -> float:
    """Bisection: the value in [low, high] above which ``happens_at(value)`` is true (false below)."""
    for _ in range(iterations):
        middle = (low + high) / 2
        low, high = (low, middle) if happens_at(middle) else (middle, high)
    return (low + high) / 2


def slide_tip_height(cell: Workcell) -> float:
    return threshold(lambda height: tips_when_pushed_at(cell, height), 0.0, cell.config.block_size)


def slides_on_incline(cell: Workcell, angle: float, friction: float, hold: float = 0.5) -> bool:
    """Whether the block (sliding ``friction``) slides more than ``SLID`` in ``hold`` seconds on a table tilted
    ``angle`` radians (gravity turned about the world y axis; the robot compensates its own weight)."""
    block = fresh_block(cell, friction)
    start = cell.data.xpos[block].copy()
    gravity = cell.model.opt.gravity.copy()
    g = float(np.linalg.norm(gravity))
    cell.model.opt.gravity[:] = [g * np.sin(angle), 0.0, -g * np.cos(angle)]
    try:
        cell.wait(hold)
    finally:
        cell.model.opt.gravity[:] = gravity
    return bool(np.linalg.norm(cell.data.xpos[block] - start) > SLID)


def slip_angle(cell: Workcell, friction: float) -> float:
    return threshold(lambda angle: slides_on_incline(cell, angle, friction), np.radians(10.0), np.radians(44.0))


def free_fall_time(cell: Workcell, drop: float) -> float:
    block = fresh_block(cell)
    half = cell.config.block_size / 2
    cell.set_body_pose(block, np.array([*BLOCK_AT, half + drop]), yaw_quaternion(0.0))
    mujoco.mj_forward(cell.model, cell.data)
    start = cell.data.time
    while not cell.touches_world(block):
        mujoco.mj_step(cell.model, cell.data)
        mujoco.mj_collision(cell.model, cell.data)
    return float(cell.data.time - start)


def settled_tower(cell: Workcell, seconds: float = 10.0) -> tuple[float, float]:
    """(largest error of a block centre's height from (k + 1/2) w, largest horizontal drift), metres."""
    cell.reset(np.random.default_rng(0), "tower")
    before = cell.block_positions()
    cell.wait(seconds)
    after = cell.block_positions()
    size = cell.config.block_size
    expected = np.sort(before[:, 2])
    levels = np.round((expected - size / 2) / size)
    height_error = float(np.max(np.abs(np.sort(after[:, 2]) - (levels + 0.5) * size)))
    drift = float(np.max(np.linalg.norm(after[:, :2] - before[:, :2], axis=1)))
    return height_error, drift


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--force", type=float, default=100.0, help="load of the penetration rows, newtons")
    parser.add_argument("--json", type=Path, help="also write the rows here (atomically)")
    parser.add_argument("--stiff-contacts", action="store_true", help="the scene with SceneConfig(stiff_contacts=True)")
    args = parser.parse_args()
    if not 0 < args.force <= 1000:
        parser.error("--force must be in (0, 1000] N")
    cell = Workcell(SceneConfig(n_blocks=4, stiff_contacts=args.stiff_contacts))
    size, mu, g = cell.config.block_size, float(cell.config.block_friction[0]), 9.81
    drop, incline_friction = 0.3, 0.5
    height_error, drift = settled_tower(cell)
    push_depth, push_force = penetration_while_pushed(cell)
    rows = [
        # (quantity, unit, analytic, measured, bound on |measured - analytic| or None for 10 %)
        (
            f"penetration into the table at {args.force:g} N",
            "mm",
            0.0,
            1e3 * penetration_into_table(cell, args.force),
            1.0,
        ),
        (
            f"penetration into the fingers or table in 4 pushes (<= {push_force:.0f} N)",
            "mm",
            0.0,
            1e3 * push_depth,
            1.0,
        ),
        (
            f"slide-versus-tip push height, w / (2 mu), mu = {mu:g}",
            "mm",
            1e3 * size / (2 * mu),
            1e3 * slide_tip_height(cell),
            None,
        ),
        (
            f"slip angle, atan(mu), mu = {incline_friction:g}",
            "deg",
            float(np.degrees(np.arctan(incline_friction))),
            float(np.degrees(slip_angle(cell, incline_friction))),
            None,
        ),
        (
            f"free-fall time from {100 * drop:g} cm, sqrt(2 h / g)",
            "ms",
            1e3 * np.sqrt(2 * drop / g),
            1e3 * free_fall_time(cell, drop),
            None,
        ),
        ("settled 4-block tower: centre heights (k + 1/2) w, error", "mm", 0.0, 1e3 * height_error, 1.0),
        ("settled 4-block tower: drift over 10 s", "mm", 0.0, 1e3 * drift, 2.0),
    ]
    print(f"{'quantity':58s} {'analytic':>9s} {'measured':>9s} {'error':>9s}  within")
    records = []
    for name, unit, analytic, measured, bound in rows:
        error = measured - analytic
        within = abs(error) <= bound if bound is not None else abs(error) <= 0.1 * abs(analytic)
        limit = f"<= {bound:g} {unit}" if bound is not None else "10 %"
        relative = f"{100 * error / analytic:+.1f} %" if bound is None else f"{error:+.2f} {unit}"
        print(f"{name:58s} {analytic:7.2f}{unit:>2s} {measured:7.2f}{unit:>2s} {relative:>9s}  {within} ({limit})")
        records.append(
            {
                "quantity": name,
                "unit": unit,
                "analytic": analytic,
                "measured": measured,
                "limit": limit,
                "within": bool(within),
            }
        )
    if args.json:
        write_atomically(args.json, json.dumps({"rows": records, "machine": machine()}, indent=2))


if __name__ == "__main__":
    main()
