"""Domain randomisation: lights, camera poses, object colours, the table, object mass and friction, depth noise.

One env option, ``randomization=``: a ``Randomization``, a dict of its fields (the rest keep their
defaults), True for the defaults, or None (the default) for none.  At every reset, once the task has laid
out its scene, ``DomainRandomizer.apply`` draws a setting from the env's seeded generator and writes it into
the compiled model: nothing recompiles, and renderers and controllers stay valid.  The next reset first
restores what it changed.  With it off nothing is drawn, so episodes are those of an env without the option.

World frame; metres, radians; colours r, g, b in 0-1.
"""

from __future__ import annotations

import colorsys
from collections.abc import Mapping
from dataclasses import dataclass, fields
from typing import Any

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation

from panda_grasp_env.geometry import is_number
from panda_grasp_env.perception.noise import DepthNoise
from panda_grasp_env.sim.workcell import Workcell

#: Cameras fixed in the world (the wrist camera rides on the hand and is not moved).
FIXED_CAMERAS = ("overhead", "front")


@dataclass(frozen=True)
class Randomization:
    """What is drawn at each reset, uniformly within these bounds.  A zero (or None) turns a part off."""

    #: Each light's direction turns by up to this angle about a random axis, radians.
    light_angle: float = 0.3
    #: Each light's diffuse intensity is scaled by a factor in this range.
    light_intensity: tuple[float, float] = (0.7, 1.3)
    #: Each fixed camera (overhead, front) moves by up to this much along each axis, metres.
    camera_shift: float = 0.01
    #: ... and turns by up to this angle about a random axis, radians.
    camera_angle: float = 0.02
    #: Every block's and object's hue moves by up to this share of the colour circle (saturation and value
    #: are kept).
    hue_shift: float = 0.02
    #: The table's colour: a (low, high) range per channel r, g, b.
    table_rgb: tuple[tuple[float, float], ...] | None = ((0.5, 0.72), (0.48, 0.7), (0.44, 0.66))
    #: Every block's and object's mass (and inertia) is scaled by a factor in this range.
    mass_scale: tuple[float, float] = (0.7, 1.4)
    #: Every block's and object's sliding friction in effect against the table, the fingers and fixtures
    #: is drawn from this range (None: the scene's).
    friction: tuple[float, float] | None = (0.6, 1.2)
    #: Depth observations carry the Kinect-like noise of ``perception.noise.DepthNoise``, its standard deviation
    #: scaled by a factor drawn from this range ((0, 0): none; no dropouts: observations stay finite).  Agents
    #: that model the sensor add that noise themselves (the planned ones do), so this is extra.
    depth_noise: tuple[float, float] = (0.0, 0.5)

    def __post_init__(self) -> None:
        for name in ("light_angle", "camera_shift", "camera_angle", "hue_shift"):
            value = getattr(self, name)
            if not (is_number(value) and 0 <= value <= LIMITS[name]):
                raise ValueError(f"randomization.{name} must be a number in [0, {LIMITS[name]}], got {value!r}")
        for name in ("light_intensity", "mass_scale", "friction", "depth_noise"):
            value = getattr(self, name)
            if value is None and name == "friction":
                continue
            if not _is_range(value, LIMITS[name]):
                raise ValueError(
                    f"randomization.{name} must be a (low, high) range within {LIMITS[name]}, got {value!r}"
                )
        table = self.table_rgb
        if table is not None and not (
            isinstance(table, (tuple, list))
            and len(table) == 3
            and all(_is_range(channel, (0.0, 1.0)) for channel in table)
        ):
            raise ValueError(f"randomization.table_rgb must be three (low, high) ranges in [0, 1], got {table!r}")

    @classmethod
    def of(cls, value: Randomization | Mapping[str, Any] | bool | None) -> Randomization | None:
        """The env option's value as a ``Randomization`` (None: off); ``ValueError`` naming a bad key."""
        if value is None or value is False:
            return None
        if value is True:
            return cls()
        if isinstance(value, Randomization):
            return value
        if not isinstance(value, Mapping):
            raise ValueError(
                f"randomization must be a Randomization, a dict of its fields, True or None, got {value!r}"
            )
        unknown = sorted(set(value) - {f.name for f in fields(cls)})
        if unknown:
            raise ValueError(f"unknown randomization key(s) {unknown}; valid: {[f.name for f in fields(cls)]}")
        return cls(**value)


#: Upper bounds of the scalar fields, and the ranges the range fields must lie in.
LIMITS: dict[str, Any] = {
    "light_angle": np.pi / 2,
    "camera_shift": 0.05,
    "camera_angle": 0.2,
    "hue_shift": 0.5,
    "depth_noise": (0.0, 10.0),
    "light_intensity": (0.0, 3.0),
    "mass_scale": (0.05, 20.0),
    "friction": (0.05, 2.0),
}


def _is_range(value: Any, bounds: tuple[float, float]) -> bool:
    pair = tuple(value) if isinstance(value, (tuple, list)) else ()
    return len(pair) == 2 and all(map(is_number, pair)) and bounds[0] <= pair[0] <= pair[1] <= bounds[1]


def _turned(rotation: np.ndarray, rng: np.random.Generator, max_angle: float) -> Rotation:
    """A rotation by up to ``max_angle`` about a random axis, applied after ``rotation``."""
    axis = rng.standard_normal(3)
    axis /= max(float(np.linalg.norm(axis)), 1e-12)
    return Rotation.from_rotvec(axis * rng.uniform(0.0, max_angle)) * Rotation.from_matrix(rotation)


def shifted_hue(rgb: np.ndarray, shift: float) -> np.ndarray:
    """``rgb`` (0-1) with its hue moved by ``shift`` of the colour circle."""
    hue, saturation, value = colorsys.rgb_to_hsv(*map(float, rgb))
    return np.array(colorsys.hsv_to_rgb((hue + shift) % 1.0, saturation, value))


class DomainRandomizer:
    """Applies a ``Randomization`` to one workcell at each reset and undoes it at the next."""

    #: The model fields a setting writes (and the next reset restores).
    FIELDS = (
        "light_dir",
        "light_diffuse",
        "cam_pos",
        "cam_quat",
        "geom_rgba",
        "body_mass",
        "body_inertia",
        "geom_friction",
        "geom_solref",
        "geom_solimp",
        "geom_priority",
    )

    def __init__(self, settings: Randomization, cell: Workcell) -> None:
        self.settings, self.cell = settings, cell
        self._saved: dict[str, np.ndarray] | None = None
        #: The depth observations' noise this episode (None: none), and its generator, both drawn at each reset.
        self.depth_noise: DepthNoise | None = None
        self.noise_rng = np.random.default_rng(0)

    def restore(self) -> None:
        """Put back what the last ``apply`` changed (before the task lays out the next scene)."""
        if self._saved is not None:
            for name, values in self._saved.items():
                getattr(self.cell.model, name)[:] = values
            self._saved = None
            self.cell.refresh_constants()

    def apply(self, rng: np.random.Generator) -> dict[str, Any]:
        """Draw and write a new setting; return what was drawn (for ``info["randomization"]``)."""
        cell, model, s = self.cell, self.cell.model, self.settings
        self._saved = {name: getattr(model, name).copy() for name in self.FIELDS}
        drawn: dict[str, Any] = {}
        for light in range(model.nlight):
            model.light_dir[light] = _turned(np.eye(3), rng, s.light_angle).apply(model.light_dir[light])
            model.light_diffuse[light] *= rng.uniform(*s.light_intensity)
        for name in FIXED_CAMERAS:
            camera = model.camera(name).id
            model.cam_pos[camera] += rng.uniform(-s.camera_shift, s.camera_shift, 3)
            orientation = np.zeros(9)
            mujoco.mju_quat2Mat(orientation, model.cam_quat[camera])
            turned = _turned(orientation.reshape(3, 3), rng, s.camera_angle)
            model.cam_quat[camera] = turned.as_quat(scalar_first=True)
        if s.table_rgb is not None:
            table = model.geom("table").id
            model.geom_rgba[table, :3] = [rng.uniform(*channel) for channel in s.table_rgb]
            drawn["table_rgb"] = model.geom_rgba[table, :3].round(4).tolist()
        masses, frictions = [], []
        for body in map(int, cell.object_ids):
            geom = model.body_geomadr[body]
            model.geom_rgba[geom, :3] = shifted_hue(model.geom_rgba[geom, :3], rng.uniform(-s.hue_shift, s.hue_shift))
            scale = rng.uniform(*s.mass_scale)
            model.body_mass[body] *= scale
            model.body_inertia[body] *= scale
            masses.append(float(model.body_mass[body]))
            if s.friction is not None:  # else the task's own (an object spec's) stays
                frictions.append(float(rng.uniform(*s.friction)))
                cell.set_object_friction(body, frictions[-1])
        cell.refresh_constants()  # masses changed; also poses the moved cameras
        scale = float(rng.uniform(*s.depth_noise))
        nominal = DepthNoise()
        self.depth_noise = (
            None
            if scale == 0
            else DepthNoise(
                nominal.base_sigma * scale, nominal.quadratic_sigma * scale, edge_dropout=0.0, random_dropout=0.0
            )
        )
        self.noise_rng = np.random.default_rng(int(rng.integers(2**63)))
        return drawn | {"masses": masses, "frictions": frictions, "depth_noise": scale}

    def noisy_depth(self, depth: np.ndarray, far: float) -> np.ndarray:
        """A depth image (H, W) metres with the setting's noise, kept within [0, far]."""
        if self.depth_noise is None:
            return depth
        return np.clip(self.depth_noise.apply(depth, self.noise_rng), 0.0, far)
