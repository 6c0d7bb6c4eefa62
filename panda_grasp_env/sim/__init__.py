"""The live simulation: the ``Workcell`` and its parts (stepping under a controller with per-step observers,
motion of the grasp site, a task's fixtures, body extents), collateral accounting, tower geometry on true poses,
start states and camera rendering."""
