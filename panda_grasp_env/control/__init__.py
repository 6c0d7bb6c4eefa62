"""How the arm is driven, on the model alone: Cartesian control and servoing through mink (``controller``),
6-DOF pose IK with the tolerance sampler (``ik``), OMPL planning and ruckig timing (``planning``)."""
