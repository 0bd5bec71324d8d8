"""Training: the jitted collect-and-update scan (``train``), populations of seeds ×
hyperparameters (``population``), the host loop with checkpoints and outputs
(``host_loop``), reporting, and reading a run directory back (``run_directory``).
"""
