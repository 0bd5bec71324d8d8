#!/bin/sh
# Table 1's brax rows: brax's own SAC and PPO at the paper's budget (preset stable: 500
# episodes, counted as episodes: docs/baselines.md, "brax SAC and PPO"), 16 seeds each,
# scored on eval seed 0's 50 episodes per arena like results/table1_stable's runs, so that
# `advisor-jax report` pools them with results/table1_stable/run_data into results/table1.
# brax trains one seed per call and cannot be vmapped over seeds, so each seed is its own
# `advisor-jax train --seed K --seeds 1` process on CPU cores BRAX_CPUS (2 per brax-SAC seed
# and 1 per brax-PPO seed fit 48 cores), timed against a 16-seed DDPG population on the
# default device (experiments/bench_brax_baselines.py). Without BRAX_CPUS the seeds run one
# after another in one process per type (a stopped one continues with `--resume`).
#   BRAX_CPUS=16-63 sh experiments/paper/brax_baselines.sh [RUNS_DIR] [RESULTS_NAME]
set -e
RUNS=${1:-runs/brax_table1}
RESULTS=${2:-results/brax_baselines_gpu}
python experiments/bench_brax_baselines.py --preset stable --seeds 16 --eval-episodes 50 \
    --agents brax-SAC brax-PPO DDPG --runs "$RUNS" --out "$RESULTS" \
    ${BRAX_CPUS:+--brax-cpus "$BRAX_CPUS"}
mkdir -p results/table1_stable/run_data_brax
python -c "
import sys; from pathlib import Path; from advisor_jax.analysis.rundata import compact_run
for a in ('brax-sac', 'brax-ppo'):
    if not Path(sys.argv[1], a).is_dir():
        continue
    for run in sorted(Path(sys.argv[1], a).glob('*/run.json')) or [Path(sys.argv[1], a, 'run.json')]:
        compact_run(run.parent, Path('results/table1_stable/run_data_brax', a, run.parent.name))
" "$RUNS"
advisor-jax report results/table1_stable/run_data results/table1_stable/run_data_no_qclip \
    results/table1_stable/run_data_d2 results/table1_stable/run_data_brax --out results/table1 \
    --items table1 fig8 fig9 fig10
