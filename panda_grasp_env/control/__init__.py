"""How the arm is driven, on the model alone: Cartesian control and servoing through mink (``controller``),
6-DOF pose IK with the tolerance sampler (``ik``), OMPL planning and ruckig timing (``planning``)."""

import importlib.util
import sys

# mink imports qpsolvers, which tries each QP backend on import: its jaxopt backend imports jax (~0.7 s;
# minari's ``create`` extra, in our test extra, installs jax) before it finds jaxopt missing and gives up.
# Without jaxopt that import can only fail, so fail it at once: qpsolvers offers the same solvers either way.
if importlib.util.find_spec("jaxopt") is None:
    sys.modules.setdefault("qpsolvers.solvers.jaxopt_osqp_", None)
