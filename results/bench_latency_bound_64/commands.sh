#!/usr/bin/env bash
# The four rounds of this page, each one process after another on one NVIDIA H200, jax 0.11.2,
# 2026-11-28, run from a directory holding two trees with the package's dependencies installed:
#   .var  = git archive eaa0e6f advisor_jax envs experiments pyproject.toml
#   .var2 = .var with program.sums_heads returning True (the layout commit 1bdf661 gives 33-64
#           bf16 agents per GPU)
#   .cur  = git archive 7f09e19 advisor_jax envs experiments pyproject.toml (round 4)
# Usage: OUT=<dir> bash commands.sh 1|2|3|4   (rows are written to $OUT/w)
set -e
ROOT=$PWD
bench() {  # bench TREE NAME ARGS...: one bench_train.py row of bf16 ATD3+AfDP, best of 3 chunks
    local tree=$1 name=$2; shift 2
    (cd "$ROOT/.$tree" && PYTHONPATH=$PWD python3 experiments/bench_train.py --preset paper \
        --agent ATD3+AfDP --precision bf16 --repeats 3 "$@" --name "$name" --out "$OUT/w")
}
mkdir -p "$OUT/w"
case ${1:-1} in
1)  # 64 and 128 agents, steady then latency-bound; 1 agent at 100- and 1,000-step chunks
    # (../bench_chunk_dispatch/)
    bench var lb_steady_64 --agents 64 --chunk 100 --program steady
    bench var lb_latency-bound_64 --agents 64 --chunk 100 --program latency-bound
    bench var chunk_100 --agents 1 --chunk 100 --program auto
    bench var chunk_1000 --agents 1 --chunk 1000 --program auto
    bench var lb_steady_128 --agents 128 --chunk 100 --program steady
    bench var lb_latency-bound_128 --agents 128 --chunk 100 --program latency-bound
    ;;
2)  # 64 agents: steady / latency-bound / latency-bound / steady
    i=0
    for P in steady latency-bound latency-bound steady; do
        i=$((i + 1))
        bench var "lb64_${i}_$P" --agents 64 --chunk 100 --program $P
    done
    ;;
3)  # 64 agents, latency-bound: .var2 (heads summed) / .var / .var / .var2
    i=0
    for T in var2 var var var2; do
        i=$((i + 1))
        bench $T "hs64_${i}_$T" --agents 64 --chunk 100 --program latency-bound
    done
    ;;
4)  # 33-63 agents, which commit 1bdf661 moved to the latency-bound program (auto picks it):
    # 48 steady / auto / auto / steady, then 40 steady / auto and 56 auto / steady
    i=0
    for spec in "48 steady" "48 auto" "48 auto" "48 steady" "40 steady" "40 auto" "56 auto" "56 steady"; do
        set -- $spec
        i=$((i + 1))
        bench cur "mid_${1}_${i}_$2" --agents "$1" --chunk 100 --program "$2"
    done
    ;;
esac
