#!/bin/sh
# Table 1's brax rows: brax's own SAC and PPO at the paper's budget (preset stable: 500
# episodes, counted as episodes: docs/baselines.md, "brax SAC and PPO"), 16 seeds each,
# scored on eval seed 0's 50 episodes per arena like results/table1_stable's runs,
# so that `advisor-jax report` pools them with results/table1_stable/run_data. brax trains
# one seed per call, so these are `advisor-jax train` runs, timed against a DDPG population
# on the same device (experiments/bench_brax_baselines.py), not a study for
# `advisor-jax sweep` (which plans vmapped populations). A run stopped midway continues with
# `advisor-jax train ... --resume` at its first unfinished seed.
#   sh experiments/paper/brax_baselines.sh [RUNS_DIR] [RESULTS_NAME]
set -e
RUNS=${1:-runs/brax_table1}
RESULTS=${2:-results/brax_baselines_gpu}
python experiments/bench_brax_baselines.py --preset stable --seeds 16 --eval-episodes 50 \
    --agents brax-SAC brax-PPO DDPG --runs "$RUNS" --out "$RESULTS"
advisor-jax report "$RUNS" results/table1_stable/run_data --out results/table1_brax \
    --items table1 --keep-runs results/table1_brax/run_data
