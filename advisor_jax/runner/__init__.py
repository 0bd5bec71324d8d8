"""Numpy-only policy runner for the physical car (paper §5.2).

Nothing in this package may import jax, flax, mujoco or anything outside the standard
library and numpy: it runs on the car's computer.
"""
