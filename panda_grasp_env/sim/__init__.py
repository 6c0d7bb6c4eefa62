"""The live simulation: the ``Workcell`` that steps MuJoCo under the controller, collateral accounting,
tower geometry on true poses, and camera rendering."""
