"""What the benchmarks and profiles in experiments/ share: provenance, timers and ceilings
(``measure``), reports (``writing``), the car runner's subject (``car_subject``), the
learner's update loop (``learner_loop``) and profiler traces (``trace``)."""
