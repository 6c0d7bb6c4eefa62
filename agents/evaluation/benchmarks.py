"""The benchmark tasks ``evaluate.py`` plays: each a registered Gymnasium id with extra ``make`` options, the
episodes (seeds) of its quick and full protocols, and whether the default protocol plays it.

Evaluation declares them, not the env: a task registers only its Gymnasium ids
(``panda_grasp_env.registration``).  The built-in benchmarks are the table at the end of this module; a task
written outside the package registers its own with ``register_benchmark`` when its module is imported
(``evaluate.py --import``), as ``docs/examples/shelf_task.py`` does.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from functools import partial
from typing import Any

from panda_grasp_env.model.meshes import EVALUATION_OBJECTS, object_by_seed
from panda_grasp_env.model.structure_suite import SUITE, tier_structures
from panda_grasp_env.model.structures import TIERS
from panda_grasp_env.registration import ENV_IDS
from panda_grasp_env.tasks.packed_layouts import ADVERSARIAL_LAYOUTS


@dataclass(frozen=True)
class Benchmark:
    """A benchmark task: the registered id it plays, the extra ``make`` options, and the episodes (seeds
    ``0 .. n - 1``) of its quick and full protocols."""

    env_id: str
    #: ``gymnasium.make`` options on top of the id's defaults.
    options: Mapping[str, Any] = field(default_factory=dict)
    #: Episodes of the quick protocol (``evaluate.py``) and of the publication one (``evaluate.py --full``).
    quick_seeds: int = field(kw_only=True)
    full_seeds: int = field(kw_only=True)
    #: ``env.reset(options=...)`` of each episode, from its seed (None: none): what one episode plays when the
    #: protocol sweeps a list (each test object in turn), not a random draw.
    reset_options: Callable[[int], dict[str, Any]] | None = field(default=None, kw_only=True)
    #: Whether ``evaluate.py`` without ``--tasks`` plays it (False: only when named, e.g. the mesh benchmarks,
    #: which need the objects extra and minutes an episode, and the 6- and 8-block towers).
    by_default: bool = field(default=True, kw_only=True)
    #: The benchmark this one varies (``TowerBuild`` for ``TowerBuild6``), or None: its planned baseline plays
    #: this one too (``panda_grasp_env.agents.evaluation.protocol.baseline``).
    variant_of: str | None = field(default=None, kw_only=True)
    #: What the planned and oracle agents see on top of ``options``; None: RGB-D from both cameras
    #: (``protocol.PERCEPTION``).
    perception: Mapping[str, Any] | None = field(default=None, kw_only=True)

    def __post_init__(self) -> None:
        object.__setattr__(self, "options", dict(self.options))

    def seeds(self, full: bool) -> int:
        """Episodes of the full protocol if ``full``, else of the quick one."""
        return self.full_seeds if full else self.quick_seeds


#: Benchmark task name -> its ``Benchmark``, in the order ``evaluate.py`` lists and plays them.
BENCHMARKS: dict[str, Benchmark] = {}


def register_benchmark(name: str, benchmark: Benchmark) -> None:
    """Make ``benchmark`` the ``evaluate.py`` task ``name``.  ``ValueError`` if the name is empty or taken, or
    the id is not registered (register the task first: ``panda_grasp_env.registration.register_task``)."""
    if not name or name in BENCHMARKS:
        raise ValueError(f"benchmark name {name!r} is empty or already registered")
    if benchmark.env_id not in ENV_IDS:
        raise ValueError(f"benchmark {name!r}: env id {benchmark.env_id!r} is not registered by any task")
    BENCHMARKS[name] = benchmark


def default_benchmarks() -> list[str]:
    """The benchmark tasks ``evaluate.py`` plays when ``--tasks`` is not given (``Benchmark.by_default``)."""
    return [name for name, benchmark in BENCHMARKS.items() if benchmark.by_default]


#: Heights (blocks) of the tall-tower benchmarks (``TowerBuild6``, ``TowerBreak8``, ...): played only when named,
#: since an episode takes two to three times a four-block one.
TALL_TOWERS = (6, 8)


def tall_tower_names(name: str) -> list[str]:
    """The tall-tower variants of benchmark ``name``: ``name6``, ``name8`` (``TALL_TOWERS``)."""
    return [f"{name}{n}" for n in TALL_TOWERS]


def with_tall_towers(name: str, benchmark: Benchmark, steps_per_block: int | None = None) -> dict[str, Benchmark]:
    """``{name: benchmark}`` and its ``tall_tower_names``: the same protocol on ``n_blocks`` 6 and 8, played only
    when named; ``steps_per_block`` gives them that many ``max_episode_steps`` per block to stack (None: the
    benchmark's own)."""
    benchmarks = {name: benchmark}
    for n, tall in zip(TALL_TOWERS, tall_tower_names(name)):
        steps = {} if steps_per_block is None else {"max_episode_steps": steps_per_block * (n - 1)}
        options = {"n_blocks": n, **benchmark.options, **steps}
        benchmarks[tall] = replace(benchmark, options=options, by_default=False, variant_of=name)
    return benchmarks


#: What the structure benchmarks' envs give every agent: target heights and poses come with the goal; the
#: heightmap covers the loose pieces' region (``sim.structure_layout.LOOSE_REGION``) at 4 mm, up to an
#: eight-cube tower's top.
STRUCTURE_OPTIONS = {
    "primitive_z": True,
    "obs_mode": "heightmap",
    "heightmap_bounds": ((0.24, 0.76), (-0.36, 0.36), (0.0, 0.45)),
    "heightmap_resolution": 0.004,
}


def structure_benchmarks() -> dict[str, Benchmark]:
    """``Structure``: the env's ``structure`` option (random structures of tiers 1-4, or yours through
    ``--task-options structure=...``); ``Structures1`` .. ``Structures6``: each tier of the named suite, one
    structure per seed in turn (seed ``s`` builds the tier's structure ``s mod n``), 10 seeds per structure in
    the full protocol; ``StructuresSample``, played by default: ``SAMPLE_STRUCTURES`` in the same way."""
    benchmarks = {
        "Structure": Benchmark(
            "PandaStructure-v0", STRUCTURE_OPTIONS, quick_seeds=5, full_seeds=50, by_default=False, perception={}
        )
    }
    tiers = {f"Structures{tier}": [s.name for s in tier_structures(tier)] for tier in range(1, len(TIERS) + 1)}
    for name, names in {**tiers, "StructuresSample": list(SAMPLE_STRUCTURES)}.items():
        benchmarks[name] = Benchmark(
            "PandaStructure-v0",
            {**STRUCTURE_OPTIONS, "max_pieces": max(len(SUITE[n].kinds) for n in names)},
            quick_seeds=len(names),
            full_seeds=10 * len(names),
            reset_options=partial(structure_of_seed, names),
            by_default=name == "StructuresSample",
            perception={},  # the heightmap of the options
        )
    return benchmarks


#: The named structures the quick protocol plays (``StructuresSample``, one seed each): two where building in
#: the first order that looks right fails, for want of a counterweight placed first (the seesaw) or of a
#: scaffold (the cantilever).
SAMPLE_STRUCTURES = ("seesaw", "cantilever")


def structure_of_seed(names: list[str], seed: int) -> dict[str, Any]:
    """The reset options of a structure benchmark's episode ``seed``: structure ``names[seed mod n]``."""
    return {"structure": names[seed % len(names)]}


#: The built-in benchmarks, in the order ``evaluate.py`` lists and plays them.
BUILT_IN_BENCHMARKS: dict[str, Benchmark] = {
    **with_tall_towers("TowerBreak", Benchmark("PandaTowerBreak-v0", quick_seeds=5, full_seeds=100)),
    **with_tall_towers(
        "TowerBreakDirectional", Benchmark("PandaTowerBreakDirectional-v0", quick_seeds=5, full_seeds=100)
    ),
    # Tall towers get the four-block tower's step limit per block to stack: five times the ideal actions.
    **with_tall_towers(
        "TowerBuild", Benchmark("PandaTowerBuild-v0", quick_seeds=5, full_seeds=100), steps_per_block=10
    ),
    "Stack": Benchmark("PandaStack-v0", quick_seeds=20, full_seeds=100),
    **with_tall_towers(
        "BuildAndBreak",
        Benchmark("PandaBuildAndBreak-v0", {"max_episode_steps": 30}, quick_seeds=1, full_seeds=10),
    ),
    "Grasp": Benchmark("PandaGrasp-v0", {"primitive_z": True}, quick_seeds=10, full_seeds=100),
    "Lift": Benchmark("PandaGrasp-v0", {"action_mode": "ee_delta"}, quick_seeds=20, full_seeds=100),
    "GraspClutter": Benchmark("PandaGraspClutter-v0", {"primitive_z": True}, quick_seeds=2, full_seeds=30),
    "GraspAdversarial": Benchmark(
        "PandaGraspAdversarial-v0", {"primitive_z": True}, quick_seeds=2, full_seeds=5 * len(ADVERSARIAL_LAYOUTS)
    ),
    # The procedural mesh set (the objects extra): 100 objects of a split, one per seed in turn.
    "GraspMeshTrain": Benchmark(
        "PandaGraspMesh-v0",
        {
            "primitive_z": True,
            "objects": [{"shape": "mesh", "split": "train", "ids": list(EVALUATION_OBJECTS["train"])}],
        },
        quick_seeds=10,
        full_seeds=300,
        reset_options=object_by_seed("train"),
        by_default=False,
    ),
    "GraspMeshTest": Benchmark(
        "PandaGraspMesh-v0",
        {"primitive_z": True, "objects": [{"shape": "mesh", "split": "test"}]},
        quick_seeds=10,
        full_seeds=300,
        reset_options=object_by_seed("test"),
        by_default=False,
    ),
    # VPG's protocol on 10 mesh objects of one split dropped in a heap.
    "GraspMeshClutterTrain": Benchmark(
        "PandaGraspMeshClutter-v0", {"primitive_z": True}, quick_seeds=2, full_seeds=30, by_default=False
    ),
    "GraspMeshClutterTest": Benchmark(
        "PandaGraspMeshClutter-v0",
        {"primitive_z": True, "objects": [{"shape": "mesh", "split": "test"}]},
        quick_seeds=2,
        full_seeds=30,
        by_default=False,
    ),
    "Push": Benchmark("PandaPush-v0", quick_seeds=20, full_seeds=100),
    "PutInBin": Benchmark("PandaPutInBin-v0", quick_seeds=10, full_seeds=100),
    **structure_benchmarks(),
}

for _name, _benchmark in BUILT_IN_BENCHMARKS.items():
    register_benchmark(_name, _benchmark)
