"""Whole motions run on a ``Workcell`` in one call: top-down grasp, place and push in the VPG parametrisation
(``top_down``), with the heights an agent leaves to the scene (``parameters``), and 6-DOF grasp poses through IK
and an OMPL plan (``pose_grasp``); both report a ``PrimitiveResult`` and share one grasp check."""
