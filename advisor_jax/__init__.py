"""advisor-jax: massively parallel advisor-based DDPG/TD3 for robot navigation.

Importing this package is cheap and pulls in no JAX: the numpy-only car runner lives in
``advisor_jax.runner`` and must import on a machine without JAX.
"""

__version__ = "0.1.0"
