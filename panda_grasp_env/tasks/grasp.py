"""Grasp: pick objects of many shapes off the table, one at a time (VPG's clutter protocol).

The task judges and rewards; how each episode's objects lie on the table (scattered, a heap, packed, or mixed)
is a layout generator of ``grasp_layouts`` that the options, and through them the ids, choose."""

from __future__ import annotations

from typing import Any

import numpy as np

from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.model.objects import SHAPES, ObjectShape, ObjectSpec
from panda_grasp_env.model.scene import SceneConfig
from panda_grasp_env.perception.heightmap import DEFAULT_BOUNDS
from panda_grasp_env.primitives.result import PrimitiveResult
from panda_grasp_env.registration import EnvId, register_task
from panda_grasp_env.sim.extents import body_bottom_height
from panda_grasp_env.sim.workcell import Workcell
from panda_grasp_env.tasks.base import Task, TaskStep, check_option, goals_reached, with_scene
from panda_grasp_env.tasks.grasp_layouts import HEAP_OBJECTS, adversarial_layout_index, grasp_layout
from panda_grasp_env.tasks.packed_layouts import MAX_OBJECTS

#: A push "changed the scene" if some object moved at least this far (metres): VPG's push reward condition.
SCENE_CHANGE = 0.01
#: After a grasp the hand is home, ~0.45 m up: an object touching the hand or the grasped one with its bottom
#: this high (metres above the table) came up with them.
CARRIED_MIN_HEIGHT = 0.15
#: Objects are in play inside this xy region (metres): the 0.448 m square the default heightmap covers,
#: VPG's workspace.  As in VPG, one pushed or rolled beyond it is out of the episode: no policy that sees
#: the workspace through the heightmap could find it.
PLAY_REGION = np.array(DEFAULT_BOUNDS[:2])
#: Low-level lift goal: this many metres above the object's resting centre (range).
LIFT_GOAL_HEIGHT = (0.05, 0.15)

#: ``properties`` entries per object: kind one-hot, geom size (3), mass, friction, lying.
OBJECT_PROPERTIES = len(SHAPES) + 6
#: The table's sliding friction: in effect against objects without their own (it equals theirs).
TABLE_FRICTION = 1.0


def shorthand_spec(shapes: tuple[str, ...] | str | None, size_ranges: dict | None) -> ObjectSpec:
    """The object spec of the ``shapes`` and ``size_ranges`` task options (``ValueError`` naming the option)."""
    try:
        ObjectSpec(shape=SHAPES if shapes is None else shapes)
    except (TypeError, ValueError) as error:
        raise ValueError(f"task option shapes: {error}") from None
    try:
        return ObjectSpec(shape=SHAPES if shapes is None else shapes, size=size_ranges)
    except (TypeError, ValueError, AttributeError) as error:
        raise ValueError(f"task option size_ranges: {error}") from None


def parsed_specs(values: list | tuple, name: str) -> list[ObjectSpec]:
    """Each of ``values`` as an ``ObjectSpec``; ``ValueError`` naming ``name[index]`` for a bad one."""
    specs = []
    for index, value in enumerate(values):
        try:
            specs.append(ObjectSpec.of(value))
        except (TypeError, ValueError) as error:
            raise ValueError(f"{name}[{index}]: {error}") from None
    return specs


#: Actions a single mesh object gets (``PandaGraspMesh-v0``): success within this budget.
MESH_ATTEMPTS = 5


@register_task
class Grasp(Task):
    """Grasp every object off the table.

    Options: ``n_objects`` (default 1; 10 with ``clutter``); ``shapes``: the
    object kinds drawn from (default all of cube, box, cylinder, sphere,
    capsule); ``size_ranges``: per-kind size ranges overriding
    ``objects.DEFAULT_SIZE_RANGES``; ``clutter``: drop the objects into a
    0.2 m square heap as VPG does (default: spread apart); ``packed``:
    ``"adversarial"`` lays out one of the hand-designed packed layouts of
    ``packed_layouts.ADVERSARIAL_LAYOUTS`` (objects wedged so that no grasp fits
    until a push frees one; ``layout``: its index or name, default drawn per
    episode; pose jitter drawn per episode), ``"random"`` a random packed grid
    (``packed_layouts.random_packed_layout``, for training); the reset
    ``info["layout"]`` names it; ``heap_share`` (with ``packed``): the share
    of episodes (0-1) that drop a heap of ``HEAP_OBJECTS`` as ``clutter`` does
    instead (``info["layout"]`` "heap"): a policy trained on packed layouts
    alone never sees objects near the workspace's edge or lying on others;
    ``max_failures``:
    consecutive failed attempts that end the episode (VPG's rule, default 10);
    ``objects``: a list of ``objects.ObjectSpec`` (or dicts of its fields), one
    per object -- shape, size, mass, friction, colour, resting pose and yaw,
    each fixed or a range drawn per episode -- instead of the ``shapes`` /
    ``size_ranges`` shorthands (one spec repeats for ``n_objects``).  The reset
    ``info["objects"]`` gives what was drawn; with ``objects`` the state vector
    also ends with it per object (``properties``: kind one-hot in ``SHAPES``
    order, geom size, mass kg, sliding friction in effect against the table,
    lying 0/1).
    A successful grasp sets the object aside (off the table).  Objects in play
    are those on the table inside ``PLAY_REGION`` (VPG's workspace; one pushed
    or rolled out of it is lost); one that lands outside it in the reset drop
    is removed from the scene.  Terminates when none is left (success if every object in
    play after the reset drop was grasped) or after ``max_failures``
    consecutive failed attempts (failed grasps, and pushes that moved nothing or carried an object out of
    play).  Reward: 1 per object a successful grasp carries out (two when it lifts one lying on the grasped
    one: both are set aside), 0.5 for a push that moved something (VPG) and lost nothing,
    and -1 per object an action carries out of play (pushed, knocked or dropped outside the region, or off
    the table), so an episode's return is objects grasped less objects lost plus 0.5 per useful push.  VPG
    pays any push that changes the scene, and a policy trained so learns to push the objects it cannot
    grasp out of the workspace.  ``info["objects_lost"]``: objects in play at the reset that are neither
    grasped nor still in play.
    Goal-conditioned (low-level modes, lift): lift object 0 to a point 5-15 cm
    above where it rests; success = within 5 cm.  The hand keeps one heading in
    these modes, so objects spread apart are turned to fit between its fingers
    (``fitting_yaw``): a box lying long side across them could not be grasped.
    """

    name = "Grasp"
    # Primitive steps by default; with action_mode="ee_delta" PandaGrasp-v0 is the goal-conditioned lift task.
    env_ids = {
        "PandaGrasp-v0": EnvId(50),
        "PandaGraspClutter-v0": EnvId(60, {"clutter": True}),
        "PandaGraspAdversarial-v0": EnvId(40, {"packed": "adversarial"}),
        "PandaGraspPacked-v0": EnvId(40, {"packed": "random"}),
        # The procedural mesh set (the objects extra): one object dropped at a random pose, a budget of
        # MESH_ATTEMPTS actions.
        "PandaGraspMesh-v0": EnvId(MESH_ATTEMPTS, {"objects": [{"shape": "mesh", "split": "train"}]}),
        # VPG's protocol on 10 mesh objects of one split dropped in a heap.
        "PandaGraspMeshClutter-v0": EnvId(60, {"objects": [{"shape": "mesh", "split": "train"}], "clutter": True}),
        # The hand-designed packed layouts and VPG's heaps, half each: one validation for both.
        "PandaGraspMixed-v0": EnvId(60, {"packed": "adversarial", "heap_share": 0.5}),
    }
    primitives = ("grasp", "push")
    goal_conditioned = True
    start_states = ("in_hand", "above_object")

    def __init__(
        self,
        n_objects: int | None = None,
        shapes: tuple[str, ...] | None = None,
        size_ranges: dict | None = None,
        clutter: bool = False,
        max_failures: int = 10,
        objects: list[ObjectSpec | dict] | None = None,
        packed: str | None = None,
        layout: int | str | None = None,
        heap_share: float = 0.0,
    ) -> None:
        check_option("clutter", clutter, isinstance(clutter, bool), "a bool")
        check_option("packed", packed, packed in (None, "adversarial", "random"), 'None, "adversarial" or "random"')
        self.packed, self.layout = packed, adversarial_layout_index(packed, layout)
        valid = is_number(heap_share) and 0 <= heap_share <= 1 and (packed is not None or heap_share == 0)
        check_option("heap_share", heap_share, valid, "a share in [0, 1], given with packed only")
        self.heap_share = float(heap_share)
        if packed is not None:
            given = {"n_objects": n_objects, "shapes": shapes, "size_ranges": size_ranges, "objects": objects}
            clashing = sorted(name for name, value in given.items() if value is not None) + ["clutter"] * clutter
            if clashing:
                raise ValueError(f"task option packed lays out its own objects: drop {clashing}")
            n_objects = MAX_OBJECTS
        check_option("max_failures", max_failures, is_count(max_failures) and max_failures >= 1, "an int >= 1")
        if objects is None:
            specs = [shorthand_spec(shapes, size_ranges)]
        else:
            check_option(
                "objects",
                objects,
                isinstance(objects, (list, tuple)) and len(objects) > 0,
                "a non-empty list of object specs",
            )
            if shapes is not None or size_ranges is not None:
                raise ValueError(
                    "task options shapes and size_ranges are shorthands for objects: give one or the other"
                )
            specs = parsed_specs(objects, "task option objects")
        default = len(specs) if len(specs) > 1 else (HEAP_OBJECTS if clutter else 1)
        n_objects = default if n_objects is None else n_objects
        check_option("n_objects", n_objects, is_count(n_objects) and 1 <= n_objects <= 30, "an int in [1, 30]")
        if len(specs) not in (1, n_objects):
            raise ValueError(f"task option n_objects={n_objects} does not match the {len(specs)} object specs")
        self.specs = specs * n_objects if len(specs) == 1 else specs
        self.n_objects, self.clutter, self.max_failures = n_objects, clutter, max_failures
        #: How each episode's objects come to lie on the table (``grasp_layouts``), as the options choose.
        self.layout_generator = grasp_layout(n_objects, clutter, packed, self.layout, self.heap_share)
        #: State-vector entries per object when specs are given (see ``properties``).
        self.properties_size = 0 if objects is None else n_objects * OBJECT_PROPERTIES
        self.drawn: list[ObjectShape] = []
        self._episode_specs: list[ObjectSpec] | None = None  # this episode's, from reset options
        self.grasped = 0
        self.consecutive_failures = 0
        self._goal = np.zeros(3)
        self._positions = np.zeros((0, 3))  # object positions after the previous step
        self.in_play = 0  # objects on the table after the reset drop
        self._remaining = 0  # objects in play after the previous step
        self._goal_body = 0

    def scene_config(self, base: SceneConfig) -> SceneConfig:
        meshes = tuple(sorted({i for spec in self.specs for i in spec.mesh_ids}))
        return with_scene(base, n_blocks=0, n_objects=self.n_objects, mesh_objects=meshes)

    reset_options = ("objects",)

    def apply_reset_options(self, cell: Workcell, options: dict[str, Any]) -> None:
        """``reset(options={"objects": [...]})``: object specs for this episode alone, as the ``objects`` task
        option takes them (one repeats for every object); mesh objects must be among those the scene compiled
        (``ValueError`` naming the others)."""
        objects = options.get("objects")
        if objects is None:
            self._episode_specs = None
            return
        if not isinstance(objects, (list, tuple)) or not objects or len(objects) not in (1, self.n_objects):
            raise ValueError(
                f"reset option objects must be a list of 1 or {self.n_objects} object specs, got {objects!r}"
            )
        specs = parsed_specs(objects, "reset option objects")
        missing = sorted({i for spec in specs for i in spec.mesh_ids} - set(cell.config.mesh_objects))
        if missing:
            raise ValueError(
                f"reset option objects: mesh objects {missing[:10]} are not in this env's scene (make it with "
                "objects whose split or ids hold them)"
            )
        self._episode_specs = specs * self.n_objects if len(specs) == 1 else specs

    @property
    def ideal_actions(self) -> int:
        return self.n_objects

    def reset(self, cell: Workcell, rng: np.random.Generator) -> dict[str, Any]:
        cell.clear()
        specs = self.specs if self._episode_specs is None else self._episode_specs
        laid_out = self.layout_generator.lay_out(cell, rng, specs, self.fixed_hand_yaw)
        shapes = self.drawn = laid_out.shapes
        # Objects that rolled out of the play region or off the table in the drop are removed from the
        # scene, and so are the rare ones a heap pressed into the table top (soft contacts; they could never
        # be lifted): what is left on the table is exactly what is in play.
        in_region = self._in_play_region(cell)
        for body, inside in zip(cell.object_ids, in_region):
            if (
                not inside
                or cell.data.xpos[body][2] < -0.05
                or body_bottom_height(cell.model, cell.data, body) < -0.005
            ):
                cell.park(body)
        self.grasped = 0
        self.consecutive_failures = 0
        self._positions = cell.object_positions()
        on_table = self.on_table(cell)
        self.in_play = self._remaining = len(on_table)
        # Low-level modes lift the first object still on the table.
        self._goal_body = on_table[0] if on_table else int(cell.object_ids[0])
        self._goal = cell.data.xpos[self._goal_body] + [0.0, 0.0, rng.uniform(*LIFT_GOAL_HEIGHT)]
        objects = [
            {
                "shape": o.kind,
                "size": tuple(float(x) for x in o.size),
                "mass": o.mass_and_inertia()[0],
                "friction": o.friction,
                "rgb": tuple(o.rgb),
                "lying": o.is_lying,
                **({"mesh": o.mesh} if o.kind == "mesh" else {}),
            }
            for o in shapes
        ]
        extra = {} if laid_out.name is None else {"layout": laid_out.name}
        return {"shapes": [o.kind for o in shapes], "objects": objects, **extra, **self._info(cell)}

    def properties(self) -> np.ndarray:
        """Per object, as drawn (with ``objects`` specs only): kind one-hot (``SHAPES`` order), geom size (m),
        mass (kg), sliding friction in effect against the table, lying (0/1)."""
        if not self.properties_size:
            return np.zeros(0, dtype=np.float32)
        rows = [
            [
                *(float(o.kind == k) for k in SHAPES),
                *o.geom_size,
                o.mass_and_inertia()[0],
                TABLE_FRICTION if o.friction is None else o.friction,
                float(o.is_lying),
            ]
            for o in self.drawn
        ]
        return np.asarray(rows, dtype=np.float32).ravel()

    def start_object(self, cell: Workcell) -> int:
        """The object to lift."""
        return self._goal_body

    def on_table(self, cell: Workcell) -> list[int]:
        """Body ids of the objects still in play: on the table inside ``PLAY_REGION`` (not set aside, not
        fallen off, not pushed or rolled out of the workspace)."""
        inside = self._in_play_region(cell)
        return [int(b) for b, ok in zip(cell.object_ids, inside) if ok and not cell.is_parked(b)]

    @staticmethod
    def _in_play_region(cell: Workcell) -> np.ndarray:
        xy = cell.data.xpos[cell.object_ids, :2]
        return np.all((xy >= PLAY_REGION[:, 0]) & (xy <= PLAY_REGION[:, 1]), axis=1)

    def _info(self, cell: Workcell, remaining: int | None = None) -> dict[str, Any]:
        remaining = len(self.on_table(cell)) if remaining is None else remaining
        return {
            "objects_grasped": self.grasped,
            "objects_remaining": remaining,
            "objects_lost": self.in_play - self.grasped - remaining,
            "consecutive_failures": self.consecutive_failures,
        }

    @staticmethod
    def _carried(cell: Workcell, grasped: int) -> set[int]:
        """The objects the hand holds at home after a grasp of ``grasped``: it, and every object touching it or
        the hand (through contacts, one object on another) whose bottom is above ``CARRIED_MIN_HEIGHT``."""
        carried, frontier = {grasped}, [grasped, *cell.robot.body_ids]
        objects = {int(b) for b in cell.object_ids}
        while frontier:
            for other in cell.bodies_touching(frontier.pop()):
                lifted = body_bottom_height(cell.model, cell.data, other) > CARRIED_MIN_HEIGHT
                if other in objects and other not in carried and lifted:
                    carried.add(other)
                    frontier.append(other)
        return carried

    def evaluate(self, cell: Workcell, result: PrimitiveResult | None) -> TaskStep:
        if result is None:
            reached = bool(goals_reached(self.achieved_goal(cell), self._goal))
            return TaskStep(0.0 if reached else -1.0, reached, False, self._info(cell))  # as compute_reward
        reward = 0.0
        grasped = result.primitive == "grasp" and result.success
        carried = 0
        if grasped:
            # Everything the hand brought home is set aside: a grasp into a heap can lift an object lying on
            # the grasped one too, which the opening hand would drop by the robot's base, out of play.
            held = self._carried(cell, cell.model.body(result.object).id)
            for body in sorted(held):
                cell.park(body)
            cell.actuate_gripper(close=False, timeout=0.4)
            cell.motion.move_home()
            carried = len(held)
            self.grasped += carried
            self.consecutive_failures = 0
            reward = float(carried)
        remaining = len(self.on_table(cell))
        lost = self._remaining - remaining - carried
        positions = cell.object_positions()
        if not grasped:
            moved = np.linalg.norm(positions - self._positions, axis=1).max()
            if result.primitive == "push" and moved >= SCENE_CHANGE and lost == 0:
                reward = 0.5  # a push that changed the scene is not a failed attempt
            else:
                self.consecutive_failures += 1
        reward -= lost
        self._positions, self._remaining = positions, remaining
        success = remaining == 0 and 0 < self.in_play == self.grasped  # nothing in play is no success
        # VPG's K-failure rule ends the trial, not the MDP: the count is not in the observation.
        gave_up = remaining > 0 and self.consecutive_failures >= self.max_failures
        return TaskStep(reward, success, remaining == 0, self._info(cell, remaining), truncated=gave_up)

    def achieved_goal(self, cell: Workcell) -> np.ndarray:
        return cell.data.xpos[self._goal_body].copy()

    def desired_goal(self) -> np.ndarray:
        return self._goal.copy()
