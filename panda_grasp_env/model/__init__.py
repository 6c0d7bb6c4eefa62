"""What is simulated: the workcell as a MuJoCo ``MjSpec`` (``scene``), the Panda's joints, site and gripper
(``robot``) and the objects' shapes, sizes and masses (``objects``).  The lowest layer of the env."""
