"""The observation / action / sensor contract and the lidar zone reduction.

Numpy only (no JAX): shared by the simulator (``envs``), the trainer, the exporter and
the numpy car runner, which must import it on a machine without JAX.
"""
