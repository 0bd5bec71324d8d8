#!/usr/bin/env bash
# The three commands of this page, one GPU each (NVIDIA H200, jax 0.11.2, 2026-11-28), run from the
# repository root with the wheels of the README's GPU set-up in .whl/ and these trees:
#   .var  = git archive eaa0e6f advisor_jax envs experiments pyproject.toml
#   .var2 = .var with program.sums_heads returning True (the layout commit 1bdf661 gives 33-64 bf16 agents per GPU)
# OUT: where the rows are written. Each round is one command: run_round 1, 2 or 3.

run_round() { case $1 in
1)  # 64 and 128 bf16 agents, steady then latency-bound; then 1 agent at 100- and 1,000-step chunks (../bench_chunk_dispatch/)
    cd .var && export PYTHONPATH=/tmp/site:$PWD
    T0=$SECONDS
    row() { left=$((575-(SECONDS-T0))); [ $left -lt 70 ] && return; timeout $left python3 experiments/bench_train.py --preset paper --agent ATD3+AfDP --precision bf16 --repeats 3 "$@" --out $OUT/w 2>&1 | grep -v "^W11" | grep "agents\|Error\|peak"; tar -czf $OUT/w.tgz -C $OUT w; echo "t=$((SECONDS-T0))"; }
    row --agents 64 --chunk 100 --program steady --name lb_steady_64
    row --agents 64 --chunk 100 --program latency-bound --name lb_latency-bound_64
    row --agents 1 --chunk 100 --program auto --name chunk_100
    row --agents 1 --chunk 1000 --program auto --name chunk_1000
    row --agents 128 --chunk 100 --program steady --name lb_steady_128
    row --agents 128 --chunk 100 --program latency-bound --name lb_latency-bound_128
    ;;
2)  # 64 bf16 agents, steady / latency-bound / latency-bound / steady
    cd .var && export PYTHONPATH=/tmp/site:$PWD
    T0=$SECONDS
    i=0
    for P in steady latency-bound latency-bound steady; do
      i=$((i+1)); left=$((540-(SECONDS-T0))); [ $left -lt 70 ] && break
      timeout $left python3 experiments/bench_train.py --preset paper --agent ATD3+AfDP --agents 64 --precision bf16 --chunk 100 --repeats 3 --program $P --name lb64_${i}_$P --out $OUT/w 2>&1 | grep -v "^W11" | grep "agents\|Error\|peak"
      tar -czf $OUT/w.tgz -C $OUT w; echo "t=$((SECONDS-T0))"
    done
    ;;
3)  # 64 bf16 agents, latency-bound: .var2 (heads summed) / .var / .var / .var2
    T0=$SECONDS; ROOT=$PWD
    i=0
    for T in var2 var var var2; do
      i=$((i+1)); left=$((540-(SECONDS-T0))); [ $left -lt 70 ] && break
      (cd $ROOT/.$T && PYTHONPATH=/tmp/site:$PWD timeout $left python3 experiments/bench_train.py --preset paper --agent ATD3+AfDP --agents 64 --precision bf16 --chunk 100 --repeats 3 --program latency-bound --name hs64_${i}_$T --out $OUT/w 2>&1 | grep -v "^W11" | grep "agents\|Error\|peak")
      tar -czf $OUT/w.tgz -C $OUT w; echo "t=$((SECONDS-T0))"
    done
    ;;
esac; }
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site .whl/*.whl
mkdir -p $OUT/w; run_round "${1:-1}"
