"""Training: the RL core's step and its chunk (``train``, ``state``), a baseline's phases
around it (``prior/``), how a population's program is built and compiled (``program``),
populations of seeds × hyperparameters (``population``), the host loop with checkpoints and
outputs (``host_loop``), reporting, reading a run directory back (``run_directory``), and
the run's advisor resolved from ``--advisor`` (``advisor_source``).
"""
