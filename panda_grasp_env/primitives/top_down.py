"""Motion primitives in world coordinates, parametrised as in Visual Pushing and Grasping.

``grasp(x, y, z, yaw)``, ``push(x, y, z, yaw, distance)``, ``place(x, y, z, yaw)`` and
``impulse(x, y, z, yaw, magnitude)`` each run a complete motion on a :class:`Workcell` and return a
:class:`PrimitiveResult`: each builds its parameters object (``primitives.parameters``: checked there) and
runs its motion (``grasp_motion``, ...: what ``primitives.registry`` lists) through ``run_motion``.  They
never raise for a bad *target* (outside the workspace, unreachable, blocked): the result says why it failed.
They raise ``ValueError`` only for malformed arguments (NaN, inf, not a number, out of range).

Positions are metres in the world frame; ``yaw`` is the heading (radians about
world z) of the gripper's closing axis for grasp and place, and the direction
of motion for push.
"""

from __future__ import annotations

from collections.abc import Callable

import mujoco
import numpy as np

from panda_grasp_env.primitives.parameters import (
    MIN_GRASP_HEIGHT,
    GraspParameters,
    ImpulseParameters,
    PlaceParameters,
    PushParameters,
)
from panda_grasp_env.primitives.result import HOLD_TIME, PrimitiveResult, closed_on, lifted_and_held, run_motion
from panda_grasp_env.sim.extents import body_bottom_height, body_extent_along
from panda_grasp_env.sim.motion import WORKSPACE
from panda_grasp_env.sim.stacking import wrap_quarter_turn
from panda_grasp_env.sim.workcell import Workcell

APPROACH_HEIGHT = 0.10  # pre-grasp / pre-place hover above the target, metres
#: A place's hover may come down to this above its goal (metres) where the workspace's top leaves no room for
#: ``APPROACH_HEIGHT``: the eighth block of a tower, its bottom at 0.35 m.  The transit comes in higher than the
#: goal's surface by ``TRANSIT_CLEARANCE``, so a hover this low still starts clear of the tower.
MIN_PLACE_APPROACH = 0.03
LIFT_HEIGHT = 0.15  # how high a grasped object is lifted, metres
SLOW_SPEED = 0.12  # m/s for the last approach and pushes
PLACE_SPEED = 0.04  # m/s while lowering a held object to contact
IMPULSE_SETTLE = 1.5  # seconds the scene runs after an impulse
PUSH_SLOW_DESCENT = 0.03  # a push's last approach runs at SLOW_SPEED over at least this many metres
PUSH_END_TOLERANCE = 0.002  # metres: the stroke runs until the grasp site is this close to its end
PUSH_END_SETTLE = 0.3  # seconds the stroke may take past its planned time to get there
PUSH_END_CORRECTIONS = 3  # times the stroke's goal moves on by what the hand still lacks (see ``_stroke``)
PUSH_BACK_OFF = 0.015  # metres the fingers back away along the stroke before rising


def _in_workspace(*points: np.ndarray) -> bool:
    return all(bool(np.all((p >= WORKSPACE[:, 0]) & (p <= WORKSPACE[:, 1]))) for p in points)


def _body_ids(*bodies: int | None) -> set[int]:
    return {int(b) for b in bodies if b is not None and b >= 0}


def grasp(cell: Workcell, x: float, y: float, z: float, yaw: float) -> PrimitiveResult:
    """Top-down grasp with the grasp site at (x, y, z) and closing axis at ``yaw`` (``grasp_motion``)."""
    return run_motion(cell, GraspParameters(x, y, z, yaw), grasp_motion)


def place(cell: Workcell, x: float, y: float, z: float, yaw: float) -> PrimitiveResult:
    """Put the held object down with its centre over (x, y), its bottom on a surface at height ``z``
    (``place_motion``)."""
    return run_motion(cell, PlaceParameters(x, y, z, yaw), place_motion)


def push(cell: Workcell, x: float, y: float, z: float, yaw: float, distance: float) -> PrimitiveResult:
    """Push from (x, y, z) in a straight line ``distance`` metres along heading ``yaw`` (``push_motion``)."""
    return run_motion(cell, PushParameters(x, y, z, yaw, distance), push_motion)


def impulse(cell: Workcell, x: float, y: float, z: float, yaw: float, magnitude: float) -> PrimitiveResult:
    """Strike the free object nearest (x, y, z) with ``magnitude`` N s along heading ``yaw`` (``impulse_motion``)."""
    return run_motion(cell, ImpulseParameters(x, y, z, yaw, magnitude), impulse_motion)


def grasp_motion(cell: Workcell, parameters: GraspParameters) -> PrimitiveResult:
    """Top-down grasp with the grasp site at (x, y, z) and closing axis at ``yaw``.

    Open; transit to above (x, y) at the transit height; the work segment: come
    straight down to ``APPROACH_HEIGHT`` above the target, descend slowly,
    close with the force-limited gripper, lift straight up by at least
    ``LIFT_HEIGHT`` (to the transit height if higher), hold ``HOLD_TIME``; then
    home.  Success: the fingers stopped short of closing on a body that rose
    >= 5 cm and is still held after the arm carried it home.  Home, as after a
    failure, so that the arm does not hide the table from the overhead camera.
    ``z`` is raised to ``MIN_GRASP_HEIGHT`` if lower.
    """
    x, y, z, yaw = parameters.values()
    z = max(z, MIN_GRASP_HEIGHT)
    target = np.array([x, y, z])
    above = target + [0.0, 0.0, APPROACH_HEIGHT]
    if not _in_workspace(target, above):
        return PrimitiveResult("grasp", False, "out_of_workspace")
    aimed = cell.surface_below(x, y)[1]
    cell.actuate_gripper(close=False, timeout=0.4)
    if not cell.motion.transit(x, y, yaw).reached:
        cell.motion.move_home()
        return PrimitiveResult("grasp", False, "unreachable", targets=_body_ids(aimed))
    body, reason = None, "ok"
    with cell.motion.one_heading(target), cell.collateral.work():  # the transit's heading: both are over (x, y)
        cell.motion.move_to(above, yaw, tolerance=0.01)
        # If the fingers land on something the grasp is still attempted where they stopped.
        cell.motion.move_to(target, yaw, speed=SLOW_SPEED, settle_timeout=0.3)
        cell.actuate_gripper(close=True)
        body = closed_on(cell)
        if body is None:
            reason = "missed"
        else:
            start_height = cell.data.xpos[body][2]
            lift = max(z + LIFT_HEIGHT, cell.motion.transit_height())
            cell.motion.move_to(np.array([x, y, lift]), yaw, settle_timeout=0.2, tolerance=0.01)
            cell.wait(HOLD_TIME)
            if not lifted_and_held(cell, body, start_height):
                reason = "dropped"
        if reason != "ok":
            cell.actuate_gripper(close=False, timeout=0.4)
            cell.motion.rise()
    cell.motion.move_home()
    if reason == "ok" and body not in cell.robot.bodies_between_fingers():
        reason = "dropped"
    if reason != "ok":
        cell.actuate_gripper(close=False, timeout=0.4)
    return PrimitiveResult(
        "grasp", reason == "ok", reason, object=cell.name_of(body), targets=_body_ids(aimed if body is None else body)
    )


def place_motion(cell: Workcell, parameters: PlaceParameters) -> PrimitiveResult:
    """Put the held object down with its centre over (x, y) and its bottom on a surface at height ``z``.

    Transit above (x, y) at the transit height (the load hanging clear of
    everything); the work segment: down to ``APPROACH_HEIGHT`` above the goal
    (less, down to ``MIN_PLACE_APPROACH``, where the workspace's top is
    nearer), lower slowly until the object touches something, open, retreat
    straight up; then home.  If (x, y) cannot be reached the object stays in the hand
    and the arm goes home.  Success: the object was released, rests with its
    centre within a quarter of the block size of (x, y) and its bottom within
    1 cm of ``z``.  ``yaw`` is the closing-axis heading during the place, measured on the held piece: a box
    that turned in the fingers (its nearest face axis off the closing axis, ``in_hand_turn``) is turned back by
    the hand, so that it lands as if the fingers had closed square on its faces.  The centre is re-aimed the
    same way, from where the piece hangs.
    """
    x, y, z, yaw = parameters.values()
    body = cell.robot.body_between_fingers()
    if body is None:
        return PrimitiveResult("place", False, "not_holding")
    name = cell.name_of(body)
    yaw -= in_hand_turn(cell, body)

    def site_goal(height_above: float) -> np.ndarray:
        """Grasp-site position that puts the held object's bottom ``height_above`` over (x, y, z)."""
        hang = cell.robot.ee_position - [*cell.data.xpos[body][:2], body_bottom_height(cell.model, cell.data, body)]
        return np.array([x, y, z + height_above]) + hang

    approach = min(APPROACH_HEIGHT, WORKSPACE[2, 1] - site_goal(0.0)[2])
    above = site_goal(approach)
    if approach < MIN_PLACE_APPROACH or not _in_workspace(above, above - [0.0, 0.0, approach]):
        return PrimitiveResult("place", False, "out_of_workspace", object=name, targets={body})
    if not cell.motion.transit(above[0], above[1], yaw).reached:
        cell.motion.move_home()
        return PrimitiveResult("place", False, "unreachable", object=name, targets={body})
    with cell.motion.one_heading(above), cell.collateral.work():  # the transit's heading, kept while re-aiming
        cell.motion.move_to(above, yaw, tolerance=0.01)
        # The object may have shifted in the fingers while travelling: re-aim from where it hangs now.
        cell.motion.move_to(site_goal(0.01), yaw, speed=SLOW_SPEED, settle_timeout=0.3)
        contact_height = site_goal(0.0)
        cell.motion.move_to(
            contact_height - [0.0, 0.0, 0.02],
            yaw,
            speed=PLACE_SPEED,
            settle_timeout=0.2,
            stop_when=lambda: cell.touches_world(body),
        )
        cell.actuate_gripper(close=False, timeout=0.5)
        cell.motion.rise(max(cell.robot.ee_position[2] + 0.08, cell.motion.transit_height()))
    cell.motion.move_home()
    centre_error = np.linalg.norm(cell.data.xpos[body][:2] - [x, y])
    bottom_error = abs(body_bottom_height(cell.model, cell.data, body) - z)
    if body in cell.robot.bodies_between_fingers() or centre_error > cell.config.block_size / 4 or bottom_error > 0.01:
        return PrimitiveResult("place", False, "placed_off", object=name, targets={body})
    return PrimitiveResult("place", True, "ok", object=name, targets={body})


def in_hand_turn(cell: Workcell, body: int) -> float:
    """How far (radians, in [-pi/4, pi/4)) the held ``body``'s nearest horizontal face axis is turned about
    world z away from the closing axis: the turn a place takes back.  0 for a body whose collision shape is not a
    box (a cylinder's or a mesh's heading means nothing).  The box's axis nearest world z is its up; one of the
    other two gives its heading (any of the four, modulo a quarter turn)."""
    geom = int(cell.model.body_geomadr[body])
    box = int(cell.model.geom_type[geom]) == int(mujoco.mjtGeom.mjGEOM_BOX)
    if not box or not (cell.model.geom_contype[geom] or cell.model.geom_conaffinity[geom]):
        return 0.0
    axes = cell.data.xmat[body].reshape(3, 3)
    up = int(np.argmax(np.abs(axes[2])))
    side = axes[:, (up + 1) % 3]
    return float(wrap_quarter_turn(np.arctan2(side[1], side[0]) - cell.robot.ee_yaw))


def push_motion(cell: Workcell, parameters: PushParameters) -> PrimitiveResult:
    """Push with the closed gripper from (x, y, z) in a straight line ``distance`` metres along heading ``yaw``.

    The fingers' flat side faces the motion, and the hand keeps one heading from the transit to the retreat
    (``Motion.one_heading``).  Transit above the start at the transit height; the work segment: come
    straight down slowly to the start, stop at the first touch -- ``"collision"``: the start is taken by
    something -- push until the grasp site is within ``PUSH_END_TOLERANCE`` of the stroke's end, back off
    ``PUSH_BACK_OFF`` along the stroke (so that the fingers leave the block's face instead of dragging it
    up), rise; then home.  The push acts on the piles (towers, heaps) of the objects its closed fingers sweep
    over the stroke (``push_line_targets``); the stroke stops with ``"collision"`` as soon as the robot
    touches anything else -- the hand is ~20 cm wide across the fingers' line and would otherwise topple a
    tower the line misses by 10 cm.  ``"no_contact"``: the stroke touched nothing.  The targets are the
    piles the robot struck.
    """
    x, y, z, yaw, distance = parameters.values()
    z = max(z, MIN_GRASP_HEIGHT)
    along = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    start = np.array([x, y, z])
    end = start + distance * along
    if not _in_workspace(start, end):
        return PrimitiveResult("push", False, "out_of_workspace")
    grip_yaw = yaw + np.pi / 2
    cell.actuate_gripper(close=True, timeout=0.4)
    reason = "ok"
    with cell.motion.one_heading(start, end):
        if not cell.motion.transit(x, y, grip_yaw).reached:
            reason = "unreachable"
        else:
            struck = cell.collateral.record.work_contacts
            on_line = push_line_targets(cell, start, end)
            with cell.collateral.work():
                # Quickly down to where the hand still clears everything around the start, then slowly.
                clear = max(cell.motion.clear_height_near(x, y), z + PUSH_SLOW_DESCENT)
                if clear < cell.robot.ee_position[2]:
                    cell.motion.move_to(
                        np.array([x, y, clear]),
                        grip_yaw,
                        settle_timeout=0.1,
                        tolerance=0.02,
                        stop_when=lambda: bool(struck),
                    )
                down = cell.motion.move_to(
                    start,
                    grip_yaw,
                    speed=SLOW_SPEED,
                    settle_timeout=0.3,
                    tolerance=0.01,
                    stop_when=lambda: bool(struck),
                )
                if struck or not down.reached:
                    reason = "collision"
                else:
                    record = cell.collateral.record  # something off the line, or a fixture, touched: stop
                    strays = lambda: bool(struck - on_line or record.fixture_collisions)  # noqa: E731
                    _stroke(cell, end, grip_yaw, strays)
                    reason = "collision" if strays() else "ok" if struck else "no_contact"
                    cell.motion.move_to(
                        cell.robot.ee_position - PUSH_BACK_OFF * along,
                        grip_yaw,
                        speed=SLOW_SPEED,
                        settle_timeout=0.1,
                        tolerance=0.005,
                    )
                cell.motion.rise()
            targets = cell.collateral.pile(struck & on_line)
    cell.motion.move_home()
    cell.actuate_gripper(close=False, timeout=0.3)
    return PrimitiveResult("push", reason == "ok", reason, targets=targets if reason != "unreachable" else set())


def _stroke(cell: Workcell, end: np.ndarray, grip_yaw: float, stop_when: Callable[[], bool]) -> None:
    """Drive the grasp site to the push stroke's ``end`` until it is within ``PUSH_END_TOLERANCE`` horizontally.
    What the hand pushes holds it back a few millimetres behind its commanded position (the arm's servos
    are stiff, not rigid), so the goal moves on by what is still missing, up to ``PUSH_END_CORRECTIONS``
    times; the stroke stops at once when ``stop_when()`` is true."""
    goal = end.copy()
    for _ in range(1 + PUSH_END_CORRECTIONS):
        cell.motion.move_to(
            goal,
            grip_yaw,
            speed=SLOW_SPEED,
            settle_timeout=PUSH_END_SETTLE,
            tolerance=PUSH_END_TOLERANCE,
            stop_when=stop_when,
        )
        short = (end - cell.robot.ee_position)[:2]
        if stop_when() or np.linalg.norm(short) <= PUSH_END_TOLERANCE:
            return
        goal[:2] += short


def push_line_targets(cell: Workcell, start: np.ndarray, end: np.ndarray) -> set[int]:
    """The piles of the objects that the closed fingers, hanging above ``start`` (world, metres), would sweep
    on a straight stroke to ``end``: objects whose footprint overlaps the fingers' band across the stroke and
    lies between the start and the end plus the fingers' own depth."""
    along = (end - start)[:2] / np.linalg.norm((end - start)[:2])
    u, n = np.array([*along, 0.0]), np.array([-along[1], along[0], 0.0])
    shift = start - cell.robot.ee_position  # the fingers, measured where the hand is, brought to the start

    def fingers_along(axis: np.ndarray) -> tuple[float, float]:
        extents = [body_extent_along(cell.model, cell.data, f, axis) for f in cell.robot.finger_bodies]
        return min(low for low, _ in extents) + shift @ axis, max(high for _, high in extents) + shift @ axis

    front = fingers_along(u)[1] - start @ u
    band = fingers_along(n)
    swept = set()
    for body in cell.object_ids:
        if cell.is_parked(int(body)):
            continue
        low_u, high_u = body_extent_along(cell.model, cell.data, body, u)
        low_n, high_n = body_extent_along(cell.model, cell.data, body, n)
        if low_n < band[1] and high_n > band[0] and high_u > start @ u and low_u < end @ u + front:
            swept.add(int(body))
    return cell.collateral.pile(swept)


def impulse_motion(cell: Workcell, parameters: ImpulseParameters) -> PrimitiveResult:
    """Strike the free object nearest (x, y, z) with a horizontal impulse of ``magnitude`` N s along heading ``yaw``.

    The source study's way of toppling a tower: the robot does not move; the
    impulse is applied at the object's centre over 10 ms, then the scene runs
    ``IMPULSE_SETTLE`` seconds.  Fails with ``"missed"`` if no object centre is
    within 5 cm of the point.  The target is the struck object's pile.
    """
    x, y, z, yaw, magnitude = parameters.values()
    distances = np.linalg.norm(cell.object_positions() - [x, y, z], axis=1)
    nearest = int(np.argmin(distances))
    if distances[nearest] > 0.05:
        cell.wait(IMPULSE_SETTLE)
        return PrimitiveResult("impulse", False, "missed")
    body = int(cell.object_ids[nearest])
    duration = 0.01
    struck_speed = magnitude / cell.model.body_subtreemass[body]  # m/s, before anything slows it
    with cell.collateral.work(), cell.physics.allowing_object_speed(2 * struck_speed):
        cell.data.xfrc_applied[body, :2] = magnitude / duration * np.array([np.cos(yaw), np.sin(yaw)])
        cell.physics.step(max(1, round(duration / cell.model.opt.timestep)))
        cell.data.xfrc_applied[body] = 0.0
        cell.wait(IMPULSE_SETTLE)
    return PrimitiveResult("impulse", True, "ok", object=cell.name_of(body), targets=cell.collateral.pile({body}))
