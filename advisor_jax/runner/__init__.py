"""Numpy-only policy runner for the physical car (paper §5.2).

Nothing in this package may import jax, flax, mujoco or anything outside the standard
library and numpy: it runs on the car's computer (tests/runner/test_no_jax.py checks it).

The observation / action contract it shares with the simulator is ``advisor_jax.contract``
(``spec``, ``zones``). Modules (imported explicitly; this file imports nothing):

* ``policy``      ``load_policy(dir) -> Policy``: verify an export, run the MLP
* ``policy_meta`` policy.json: schema, hashes, checks against the trained values
* ``observation`` RPLIDAR scan + tracked pose + goal → 20-d observation
* ``lidar_zones`` RPLIDAR readings → 16 zones by spec.py's rule (tick table)
* ``drive``       (V, ω) → differential or Ackermann commands
* ``loop``        fixed-rate control loop with a watchdog; ``cyclelog`` its JSONL log
* ``replay``      re-run a log and check every decision
* ``hardware``    lidar / pose / motor interfaces and adapters
* ``onnx_model``  the MLP as an ONNX graph (optional ``onnx`` extra)
* ``cli``         the ``advisor-jax-car`` command
"""
