"""Numpy-only policy runner for the physical car (paper §5.2).

Nothing in this package may import jax, flax, mujoco or anything outside the standard
library and numpy: it runs on the car's computer (tests/runner/test_no_jax.py checks it).

Modules (imported explicitly; this file imports nothing, so the simulator's use of
``zones`` stays cheap):

* ``spec``        observation / action / zone contract shared with the simulator
* ``zones``       lidar beams → 16 zones (numpy or jax.numpy)
* ``policy``      ``load_policy(dir) -> Policy``: verify an export, run the MLP
* ``observation`` RPLIDAR scan + tracked pose + goal → 20-d observation
* ``drive``       (V, ω) → differential or Ackermann commands
* ``loop``        fixed-rate control loop with a watchdog; ``cyclelog`` its JSONL log
* ``replay``      re-run a log and check every decision
* ``hardware``    lidar / pose / motor interfaces and adapters
* ``onnx_model``  the MLP as an ONNX graph (optional ``onnx`` extra)
* ``cli``         the ``advisor-jax-car`` command
"""
