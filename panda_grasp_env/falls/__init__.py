"""Falling towers recorded in the simulation: the data the fall-dynamics model learns from.

* ``recorder`` -- records falling-tower sequences from the env (``python -m panda_grasp_env.falls``);
* ``settings`` -- the recorder's checked settings (``RecorderSettings``);
* ``shards`` -- the shard format the recorder writes and its ``metadata.json``.

The model, its training runs and the shipped models are ``panda_grasp_env.agents.learning.falls``: this
package holds no torch and trains nothing.
"""
