"""The Panda workcell, built programmatically with ``mujoco.MjSpec``.

The Franka Panda arm and hand come from the MJCF files shipped inside the installed
``gymnasium-robotics`` package (``panda_asset``).  On top of them this module adds a table, free blocks,
finger pads, gravity compensation, a grasp site between the fingertips, and the cameras and lights of
``cameras``.

World frame: origin at the robot base on the table top, +x away from the robot,
+z up.  All lengths are metres, all angles radians, masses kilograms.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import mujoco
import numpy as np

from panda_grasp_env.geometry import is_count, is_number
from panda_grasp_env.model.cameras import (
    CAMERA_NAMES,
    CameraConfig,
    add_fixed_cameras,
    add_lights,
    add_wrist_camera,
)
from panda_grasp_env.model.meshes import MAX_PARTS, add_mesh_assets, split_of
from panda_grasp_env.model.panda_asset import panda_spec

ARM_JOINTS = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
FINGER_JOINTS = ("robot:panda0_finger_joint1", "robot:panda0_finger_joint2")
ARM_ACTUATORS = tuple(f"panda0_joint{i}" for i in range(1, 8))
FINGER_ACTUATORS = ("r_gripper_finger_joint", "l_gripper_finger_joint")
HAND_BODY = "panda0_link7"
FINGER_BODIES = ("panda0_leftfinger", "panda0_rightfinger")
GRASP_SITE = "grasp_site"
GOAL_MARKER = "goal_marker"
#: Distance from link7's origin to the grasp site, along the hand axis (centre of the finger pads).
GRASP_SITE_OFFSET = 0.2454
#: How far each finger pad stands proud of the finger's rest position towards the other finger.
PAD_PROTRUSION = 0.0035
#: Maximum distance between the finger pads when fully open (each finger slides 0-0.04 m).
MAX_FINGER_GAP = 0.08 - 2 * PAD_PROTRUSION
#: Softness of the world's contacts and the finger pads (time constant s, damping ratio; impedance from 0.95 to
#: 0.99 over 1 mm of penetration): as stiff as MuJoCo allows at the 2 ms step (a time constant of two steps).
#: MuJoCo's defaults (0.02 s; 0.9-0.95) let a 5 cm block pressed with 100 N sink 5 mm into the table, a pushed
#: block's leading edge dig in 12 mm, and a held block creep in the fingers; these keep each under 1 mm
#: (``benchmarks/physics_conformance.py``).
#: Noslip post-pass iterations of the primitive action modes (see ``build_spec``); low-level modes use none.
PRIMITIVE_NOSLIP_ITERATIONS = 3
CONTACT_SOLREF = (0.004, 1.0)
CONTACT_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)
#: Each finger's push face, a box in the finger's frame (metres; x along a push, y the closing axis, z towards
#: the tip): half sizes and centre (y outward from the inner face, mirrored for the right finger).
PUSH_FACE_HALF_SIZE = (0.0201, 0.006, 0.03375)
PUSH_FACE_CENTRE = (0.0, 0.010, 0.05875)
#: Geom priorities: a contact takes the friction, solref and solimp of its higher-priority geom.
PAD_PRIORITY, OWN_FRICTION_PRIORITY = 1, 2
MAX_OBJECTS = 30
#: Geom group of geoms that are not drawn: an object slot's geoms its current shape does not use.
HIDDEN_GROUP = 3

#: The blocks' colours, in block order (r, g, b in 0-1).  The first four are the source study's tower (yellow
#: for its violet); the other four, for towers of up to eight, sit in the gaps between them on the hue circle,
#: at least 19 of OpenCV's 180 hue units from any other, beside colour segmentation's half-window of 10
#: (``panda_grasp_env.perception.segmentation.HUE_WINDOW``): red 1, yellow 26, lime 45, green 65, cyan 90,
#: blue 114, purple 136, magenta 158.  They are darker (no channel above 0.8) so that a lit top face clips no
#: channel, which turned a brighter lime's top faces (0.5, 0.9, 0.1) to hue 32, inside yellow's window.  No
#: orange: 12 units from red and 13 from yellow, it would fall inside both of their windows.
DEFAULT_COLOURS: dict[str, tuple[float, float, float]] = {
    "red": (0.85, 0.12, 0.10),
    "green": (0.10, 0.70, 0.20),
    "blue": (0.10, 0.25, 0.85),
    "yellow": (0.95, 0.85, 0.10),
    "lime": (0.38, 0.70, 0.06),
    "cyan": (0.10, 0.80, 0.80),
    "purple": (0.42, 0.08, 0.72),
    "magenta": (0.72, 0.08, 0.54),
}
#: Every block's colour where a block task's ``block_colours`` option is ``"uniform"``: a light grey, without
#: hue, so that domain randomisation's per-block hue shifts leave the blocks alike (r, g, b in 0-1).
UNIFORM_BLOCK_COLOUR = (0.85, 0.85, 0.85)


@dataclass(frozen=True)
class SceneConfig:
    """Everything that shapes the MuJoCo model.  Lengths in metres, masses in kg."""

    n_blocks: int = 4
    #: Free objects of variable shape (``object_<i>``) for grasping tasks; their
    #: shape, size and colour are set at each reset (see ``panda_grasp_env.model.objects``).
    n_objects: int = 0
    #: Ids of the mesh set's objects (``panda_grasp_env.model.meshes``) the object slots can take: their meshes
    #: are compiled in, and each slot carries ``meshes.MAX_PARTS`` mesh geoms besides its primitive one.
    mesh_objects: tuple[int, ...] = ()
    block_size: float = 0.05
    block_mass: float = 0.1
    #: Sliding, torsional and rolling friction coefficients of the blocks.
    block_friction: tuple[float, float, float] = (1.0, 0.005, 0.0001)
    colours: dict[str, tuple[float, float, float]] = field(default_factory=lambda: dict(DEFAULT_COLOURS))
    #: Maximum squeezing force of each finger, newtons (the real Panda hand holds 70 N).
    gripper_force: float = 20.0
    timestep: float = 0.002
    #: MuJoCo's noslip post-pass iterations.  None: the env's choice for its action mode (primitives
    #: ``PRIMITIVE_NOSLIP_ITERATIONS``, low-level modes 0), and ``PRIMITIVE_NOSLIP_ITERATIONS`` for a scene
    #: built directly; so a ``scene`` given to ``make`` for other reasons keeps the mode's physics.
    noslip_iterations: int | None = None
    #: The world's contacts (table, objects, fixtures) at ``CONTACT_SOLREF`` / ``CONTACT_SOLIMP`` instead of
    #: MuJoCo's defaults: a block under 100 N sinks 0.2 mm instead of 5 mm.  Off by default until the shipped
    #: low-level policies are retested on it: the scripted Push expert fell from 98 % to 91 % of 300 held-out
    #: seeds with it (``benchmarks/physics_conformance.py --stiff-contacts``, docs/measured-figures.md), and a
    #: brief touch can fall between the control steps at which primitives read contacts.
    stiff_contacts: bool = False
    #: A flat push face over each finger's front and back (``PUSH_FACE_HALF_SIZE``), so that a push meets a block
    #: with a vertical plane instead of the asset's capsule stack, whose widest capsule rides up the block's top
    #: edge.  Off by default until the grasping policies are retested on it: the faces widen the fingertips by
    #: 4 mm each side, and the oracle then missed 9 grasps on a 3-object heap it cleared without them.
    push_faces: bool = False
    #: MuJoCo's island sleeping (``mjENBL_SLEEP`` at its default ``sleep_tolerance``, 1e-3): free bodies that
    #: have come to rest leave collision detection and the solver until an awake body touches them, a force
    #: or a written pose wakes them.  The arm carries actuators and never sleeps.  None: on where the scene has
    #: ``mesh_objects``, whose resting 10-object heap made each step cost 2.5 times a primitive heap's awake
    #: (``benchmarks/primitive_overhead.py``), and off elsewhere, so that the block tasks' physics and figures
    #: stay as measured.
    sleep: bool | None = None
    #: Iterations of the Newton solver's line search (MuJoCo's ``ls_iterations``).  None: MuJoCo's default,
    #: 50, where the scene has ``mesh_objects``, and 20 elsewhere.  Capped at 20, an object of 17 g pinched
    #: between the pads left the solve at a point that threw it at 8-16 m/s, a physics error (GraspMeshTest
    #: seed 65294, object 994; from 25 on it settles); the block tasks' physics and figures stay as measured.
    line_search_iterations: int | None = None
    #: Time constant of the finger pads' contacts, seconds (their damping ratio is 1).  None: 10 ms where the
    #: scene has ``mesh_objects``, and ``CONTACT_SOLREF``'s 4 ms elsewhere.  The mesh objects weigh 10-60 g:
    #: pads as stiff as MuJoCo allows at this step pinched a 23 g object 4 mm deep and the solve threw it at
    #: 9.9 m/s (a physics error; GraspMeshClutterTrain seed 5000013), where 6 ms left it at 1.8 m/s and 10 ms
    #: at 1.1; the blocks (100 g) keep the stiff pads and their figures.
    pad_time_constant: float | None = None
    cameras: dict[str, CameraConfig] = field(
        default_factory=lambda: {
            "overhead": CameraConfig(640, 480, 45.0),  # Kinect-like vertical field of view
            "front": CameraConfig(640, 480, 45.0),
            "wrist": CameraConfig(320, 240, 60.0),
        }
    )
    #: Adds static fixtures (a bin, walls) to the spec after the table: a task's ``add_fixtures``.
    fixtures: Callable[[mujoco.MjSpec], None] | None = None

    def __post_init__(self) -> None:
        if not is_count(self.n_blocks) or not 0 <= self.n_blocks <= len(self.colours):
            raise ValueError(
                f"n_blocks must be an int between 0 and the number of colours ({len(self.colours)}), got {self.n_blocks!r}"
            )
        if not is_count(self.n_objects) or not 0 <= self.n_objects <= MAX_OBJECTS:
            raise ValueError(f"n_objects must be an int between 0 and {MAX_OBJECTS}, got {self.n_objects!r}")
        if self.n_blocks + self.n_objects == 0:
            raise ValueError("the scene needs at least one block or object")
        if not isinstance(self.mesh_objects, tuple) or (self.mesh_objects and not self.n_objects):
            raise ValueError(
                f"mesh_objects must be a tuple of mesh set ids, with n_objects > 0, got {self.mesh_objects!r}"
            )
        for object_id in self.mesh_objects:
            split_of(object_id)  # ValueError naming an id outside the set
        for name in ("block_size", "block_mass", "gripper_force", "timestep"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name} must be a positive finite number, got {value!r}")
        if self.block_size > 0.07:
            raise ValueError(f"block_size must fit the gripper (<= 0.07 m), got {self.block_size}")
        if self.noslip_iterations is not None and not (
            is_count(self.noslip_iterations) and self.noslip_iterations >= 0
        ):
            raise ValueError(f"noslip_iterations must be an int >= 0 or None, got {self.noslip_iterations!r}")
        if self.sleep is not None and not isinstance(self.sleep, bool):
            raise ValueError(f"sleep must be a bool or None, got {self.sleep!r}")
        if self.pad_time_constant is not None and not (
            is_number(self.pad_time_constant) and self.pad_time_constant >= 2 * self.timestep
        ):
            raise ValueError(
                f"pad_time_constant must be a number of seconds >= 2 timesteps or None, got {self.pad_time_constant!r}"
            )
        if self.line_search_iterations is not None and not (
            is_count(self.line_search_iterations) and self.line_search_iterations >= 1
        ):
            raise ValueError(f"line_search_iterations must be an int >= 1 or None, got {self.line_search_iterations!r}")
        for name in ("stiff_contacts", "push_faces"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} must be a bool, got {getattr(self, name)!r}")
        if len(self.block_friction) != 3 or not all(np.isfinite(f) and f >= 0 for f in self.block_friction):
            raise ValueError(f"block_friction must be three non-negative numbers, got {self.block_friction!r}")
        unknown = set(self.cameras) - set(CAMERA_NAMES)
        if unknown:
            raise ValueError(f"unknown camera(s) {sorted(unknown)}; valid: {list(CAMERA_NAMES)}")
        if self.fixtures is not None and not callable(self.fixtures):
            raise ValueError(f"fixtures must be a function of the MjSpec or None, got {self.fixtures!r}")

    @property
    def block_names(self) -> list[str]:
        return [f"block_{colour}" for colour in list(self.colours)[: self.n_blocks]]

    @property
    def object_names(self) -> list[str]:
        return [f"object_{i}" for i in range(self.n_objects)]


def _set_damping(joint: mujoco.MjsJoint, value: float) -> None:
    # MuJoCo 4 made joint damping a 3-vector (polynomial coefficients); 3.x has a scalar.
    if np.ndim(joint.damping) == 0:
        joint.damping = value
    else:
        joint.damping = [value, 0.0, 0.0]


def build_spec(config: SceneConfig, with_environment: bool = True, self_collision: bool = False) -> mujoco.MjSpec:
    """Assemble the workcell as an ``MjSpec`` (not yet compiled).

    ``with_environment=False`` gives the robot alone (same kinematics, no table,
    blocks or fixed cameras): the model the inverse kinematics solves on.
    ``self_collision=True`` lets the links collide with each other (the motion
    planner's model; the simulation leaves it off).
    """
    spec = panda_spec()
    spec.modelname = "panda_workcell"

    # Physics.  2 ms steps keep 5 cm / 0.1 kg block contacts (solref time constant
    # 20 ms >= 2 timesteps) stiff and stable.  implicitfast integrates the arm's
    # joint damping and stiff position servos implicitly, so they cannot blow up.
    # Elliptic friction cones with impratio 10 make friction constraints stiffer
    # than normal ones, which stops slow slip of a held block and creep in a tower.
    spec.option.timestep = config.timestep
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    spec.option.solver = mujoco.mjtSolver.mjSOL_NEWTON
    if mujoco.__version__ == "4.0.0":
        # 4.0.0's sparse Cholesky factorisation gives the Newton solver a wrong Hessian factor when the
        # constraint Jacobian is sparse (google-deepmind/mujoco#3767, fixed in 4.0.1).  MuJoCo makes it
        # sparse from 60 dofs on (the ten-object scenes), where fingers closing on packed cubes then threw
        # them at 18-64 m/s.  The dense Jacobian gives the solution 3.17 gives, at ~1.4x the step time there.
        spec.option.jacobian = mujoco.mjtJacobian.mjJAC_DENSE
    spec.option.iterations = 50
    line_search = config.line_search_iterations
    spec.option.ls_iterations = line_search or (50 if config.mesh_objects else 20)  # SceneConfig says why
    # The noslip post-pass removes the residual creep of soft friction: without
    # it a held block drifted up to 9 mm in the fingers during a carry (place
    # error); with 3 passes <= 2.5 mm.  It costs ~25 % of mj_step's rate.
    noslip = config.noslip_iterations
    spec.option.noslip_iterations = PRIMITIVE_NOSLIP_ITERATIONS if noslip is None else noslip
    if config.sleep or (config.sleep is None and config.mesh_objects):
        spec.option.enableflags |= mujoco.mjtEnableBit.mjENBL_SLEEP
    spec.visual.quality.offsamples = 4
    spec.visual.map.znear = 0.01
    spec.stat.center = [0.4, 0.0, 0.2]
    spec.stat.extent = 1.2

    # Robot: gravity compensation on every link so the position servos need no
    # integral term, and lighter finger dynamics than the asset's (armature 5
    # made the fingers take seconds to close).
    for body in spec.bodies:
        if body.name.startswith("panda0_"):
            body.gravcomp = 1.0
    for joint_name in FINGER_JOINTS:
        joint = spec.joint(joint_name)
        joint.armature = 0.01
        _set_damping(joint, 5.0)
        # A limit's force scales with the joint's effective mass, and these fingers are light: with MuJoCo's
        # default limit softness (time constant 0.02 s) an opening finger overshot its stop by 9.6 mm, and
        # objects pressed fingers up to 15 mm past it, so an "open" hand clamped two boxes wedged between its
        # fingers and carried them home.  Twice the time step is as stiff as MuJoCo recommends: 1.5 mm for a
        # moment as an opening finger meets its stop at full speed, <= 0.6 mm under load.
        joint.solref_limit = [2 * config.timestep, 1.0]
        joint.solimp_limit = [0.95, 0.99, 0.001, 0.5, 2.0]
    for actuator_name in FINGER_ACTUATORS:
        actuator = spec.actuator(actuator_name)
        actuator.forcerange = [-config.gripper_force, config.gripper_force]
    for joint_name in ARM_JOINTS:
        _set_damping(spec.joint(joint_name), 40.0 if joint_name[-1] in "1234" else 8.0)

    hand = spec.body(HAND_BODY)
    site = hand.add_site()
    site.name = GRASP_SITE
    site.pos = [0.0, 0.0, GRASP_SITE_OFFSET]
    # The asset's fingers slide along their y axis, rotated -45 deg about the hand
    # axis: +45 deg makes the site's x axis the closing axis, z the approach direction.
    site.quat = [0.92388, 0.0, 0.0, 0.382683]
    site.size = [0.005, 0.005, 0.005]
    site.group = 4

    pad_time_constant = config.pad_time_constant or (0.01 if config.mesh_objects else CONTACT_SOLREF[0])
    # Finger pads: thin high-friction boxes on the inner face of each fingertip,
    # standing 2.5 mm proud of the asset's slanted finger capsules: when the
    # capsules touched a block they wedged it sideways out of the grasp.
    # condim 4 adds torsional friction so a held block cannot pivot between the pads.
    for finger in FINGER_BODIES:
        # The asset's finger collision geoms carry a torsional friction coefficient of 0.5 m (a contact
        # patch half a metre across).  An object pinched between them near the table could take ~1.4 N·m
        # of torsion within that bound in one 2 ms step and leave at 3-9 m/s (~2.4 % of low-level lift
        # episodes).  They take the blocks' coefficient; the pad holds the grasp.
        for geom in spec.body(finger).geoms:
            if geom.contype:
                geom.friction = [geom.friction[0], config.block_friction[1], geom.friction[2]]
        pad = spec.body(finger).add_geom()
        pad.name = f"{finger}_pad"
        pad.type = mujoco.mjtGeom.mjGEOM_BOX
        pad.size = [0.0085, PAD_PROTRUSION, 0.012]
        pad.pos = [0.0, 0.0, 0.08]
        pad.friction = [1.5, 0.01, 0.0001]
        pad.condim = 4
        # Like the asset's finger capsules: collide with the world, not with each other.
        pad.contype = 1
        pad.conaffinity = 0
        pad.rgba = [0.2, 0.2, 0.2, 1.0]
        pad.mass = 0.0
        pad.priority = PAD_PRIORITY
        pad.margin = 0.0
        pad.solref, pad.solimp = [pad_time_constant, CONTACT_SOLREF[1]], list(CONTACT_SOLIMP)  # no creep

    # Push faces: a flat box over the front and back of each finger's outer half.  The asset's finger is a
    # stack of capsules that widens by 4 mm towards the hand, so a pushing finger met a block with the capsule
    # at its top edge, pressed it into the table (up to 150 N) and stalled, or tipped it; the box makes the
    # fingers' side a vertical plane from 2 mm above the tips up.  It stays 4 mm clear of the inner face, so
    # grasps still close on the pads.
    for finger in FINGER_BODIES if config.push_faces else ():
        face = spec.body(finger).add_geom()
        face.name = f"{finger}_push_face"
        face.type = mujoco.mjtGeom.mjGEOM_BOX
        face.size = list(PUSH_FACE_HALF_SIZE)
        face.pos = [
            0.0,
            PUSH_FACE_CENTRE[1] if finger.startswith("panda0_left") else -PUSH_FACE_CENTRE[1],
            PUSH_FACE_CENTRE[2],
        ]
        face.contype, face.conaffinity = 1, 0
        face.friction = [1.0, config.block_friction[1], config.block_friction[2]]  # not the finger class's 0.5 m
        face.rgba = [0.2, 0.2, 0.2, 1.0]
        face.mass = 0.0
        face.margin = 0.0

    add_wrist_camera(hand, config.cameras)

    if config.stiff_contacts:
        # The world's contacts as stiff as the step allows, through the default class: the table, the objects
        # and a task's fixtures.  The robot's geoms keep the asset's softness, but for the finger pads (set
        # above): with the finger-object contact this stiff too, the Push expert's 25 Hz pushes lost the block
        # on 13 of 40 seeds instead of 5.
        spec.default.geom.solref = list(CONTACT_SOLREF)
        spec.default.geom.solimp = list(CONTACT_SOLIMP)

    # Geom groups: 0 world, 1 robot visual meshes (pretty renders), 2 robot
    # collision geoms (fast renders: 2.3 k instead of 134 k triangles), 3 hidden (unused
    # object-slot geoms), 4 sites.
    for geom in spec.geoms:
        if geom.name.endswith("_pad") or geom.contype or geom.conaffinity:
            geom.group = 2
            # Opaque, so they write depth in RGB-D renders (translucent geoms don't).
            geom.rgba = [*geom.rgba[:3], 1.0]
            # Contacts with the world (contype 1 meets the world's conaffinity 1) but not between
            # links: the controller never folds the arm into itself, and the link-link checks
            # were ~30 % of a physics step.  Motion planning checks self-collision on its own.
            geom.conaffinity = 1 if self_collision and not geom.name.endswith("_pad") else 0
        else:
            geom.group = 1

    if with_environment:
        _add_environment(spec, config)
    return spec


def _add_environment(spec: mujoco.MjSpec, config: SceneConfig) -> None:
    world = spec.worldbody
    tex = spec.add_texture()
    tex.name = "table_tex"
    tex.type = mujoco.mjtTexture.mjTEXTURE_2D
    tex.builtin = mujoco.mjtBuiltin.mjBUILTIN_FLAT
    tex.rgb1 = [0.55, 0.55, 0.52]
    tex.width = tex.height = 16
    floor_mat = spec.add_material()
    floor_mat.name = "floor_mat"
    floor_mat.rgba = [0.25, 0.27, 0.30, 1.0]

    add_lights(world)

    # Table top at z = 0 under the robot base; a floor catches anything pushed off.
    table = world.add_geom()
    table.name = "table"
    table.type = mujoco.mjtGeom.mjGEOM_BOX
    table.size = [0.65, 0.6, 0.02]
    table.pos = [0.35, 0.0, -0.02]
    table.rgba = [0.62, 0.60, 0.56, 1.0]
    table.friction = [1.0, 0.005, 0.0001]
    floor = world.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [3.0, 3.0, 0.1]
    floor.pos = [0.0, 0.0, -0.75]
    floor.material = "floor_mat"
    if config.fixtures is not None:
        config.fixtures(spec)

    for name, colour in zip(config.block_names, config.colours.values()):
        geom = _add_free_cube(world, name, config, list(config.block_friction), condim=3)
        geom.rgba = [*colour, 1.0]
    parts = add_mesh_assets(spec, config.mesh_objects)
    for name in config.object_names:
        # Object slots start as cubes; tasks set type, size, mass and colour at reset (Workcell.set_object_shapes).
        # Rolling friction (condim 6, 2 mm): without it a dropped sphere or capsule rolled off the table.
        cube = _add_free_cube(world, name, config, [*config.block_friction[:2], 0.002], condim=6)
        for index in range(MAX_PARTS if parts else 0):
            # Mesh geoms, hidden until a mesh object takes the slot (objects.apply_shape).  Compiled to collide
            # (MuJoCo 4 lets no other geom collide later); the workcell switches their contacts off.
            geom = spec.body(name).add_geom()
            geom.name = f"{name}_part_{index}"
            geom.type = mujoco.mjtGeom.mjGEOM_MESH
            geom.meshname = parts[0]
            geom.group = HIDDEN_GROUP
            geom.mass = 0.0
            geom.friction, geom.condim = cube.friction, cube.condim

    # Goal region marker for goal-conditioned tasks: a flat translucent disc,
    # hidden under the table until a task moves it (it has no collision).
    marker = world.add_site()
    marker.name = GOAL_MARKER
    marker.type = mujoco.mjtGeom.mjGEOM_CYLINDER
    marker.size = [0.05, 0.0005, 0.0]
    marker.pos = [0.5, 0.0, -0.5]
    marker.rgba = [0.1, 0.9, 0.2, 0.5]
    marker.group = 0
    add_fixed_cameras(world, config.cameras)


def _add_free_cube(
    world: mujoco.MjsBody, name: str, config: SceneConfig, friction: list[float], condim: int
) -> mujoco.MjsGeom:
    """A free body ``name`` (joint ``<name>_joint``) with one cube geom ``<name>_geom`` of the block size."""
    half = config.block_size / 2
    body = world.add_body()
    body.name = name
    body.pos = [0.5, 0.0, half]
    body.add_freejoint().name = f"{name}_joint"
    geom = body.add_geom()
    geom.name = f"{name}_geom"
    geom.type = mujoco.mjtGeom.mjGEOM_BOX
    geom.size = [half, half, half]
    geom.mass = config.block_mass
    geom.friction = friction
    geom.condim = condim
    return geom


#: The scene's own static collision geoms: everything else static outside the robot is a task's fixture.
SCENE_GEOMS = ("table", "floor")


def fixture_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Ids of the fixtures' collision geoms (a task's ``add_fixtures``): static (welded to the world), not
    the robot's, not the table or the floor."""
    names = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(model.ngeom)]
    bodies = [mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, int(b)) or "" for b in model.geom_bodyid]
    return np.array(
        [
            g
            for g in range(model.ngeom)
            if model.body_weldid[model.geom_bodyid[g]] == 0
            and not bodies[g].startswith("panda0_")
            and names[g] not in SCENE_GEOMS
            and (model.geom_contype[g] or model.geom_conaffinity[g])
        ],
        dtype=int,
    )


def fixture_name(model: mujoco.MjModel, geom: int) -> str:
    """What a fixture geom belongs to, by name: its body's (a body of the world's), else its own (a geom
    added to the world body), else ``fixture_<geom id>``."""
    body = int(model.geom_bodyid[geom])
    named = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, body) if body else None
    return named or mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, geom) or f"fixture_{geom}"


def fixture_elements(model: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """(fixture bodies other than the world, fixture geoms): the model entries whose pose and size a task may
    change per episode, and that a copy of the scene (the motion planner's) takes over."""
    geoms = fixture_geoms(model)
    bodies = np.unique(model.geom_bodyid[geoms])
    return bodies[bodies > 0], geoms


def build_model(config: SceneConfig | None = None) -> mujoco.MjModel:
    """Compile the workcell into an ``MjModel``."""
    return build_spec(config or SceneConfig()).compile()
