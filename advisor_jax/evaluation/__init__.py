"""Deterministic evaluation of policies and populations, and the closed loop that drives
the numpy car runner in the simulator.
"""
