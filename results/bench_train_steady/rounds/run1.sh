# issue 17, round 1: steady program (no lax.cond per step) and command-buffer scheduling modes,
# 1 agent bf16, 1000-step chunks, best of 5, one process per setting, alternating with HEAD (.ref).
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/r1
B="experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --out $OUT/r1"
one() { name=$1; shift; echo "== $name XLA_FLAGS=$XLA_FLAGS"; timeout 150 python3 $B --name $name "$@" 2>&1 | grep -E "env-steps|Error|error" | tail -3; }
ref() { name=$1; shift; echo "== $name (ref) XLA_FLAGS=$XLA_FLAGS"; (cd .ref && PYTHONPATH=$PWD:$PYTHONPATH timeout 150 python3 $B --name $name "$@" 2>&1 | grep -E "env-steps|Error|error" | tail -3); }
export XLA_FLAGS=
one tree_bf16 --precision bf16
ref ref_bf16 --precision bf16
export XLA_FLAGS=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT_REGIONS
one tree_bf16_cr --precision bf16
ref ref_bf16_cr --precision bf16
export XLA_FLAGS=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT
one tree_bf16_cc --precision bf16
export XLA_FLAGS=--xla_gpu_enable_command_buffer=+WHILE
one tree_bf16_while --precision bf16
export XLA_FLAGS=
one tree_fp32 --precision fp32
ref ref_fp32 --precision fp32
one tree_bf16_b --precision bf16
rm -f $OUT/r1/*.md
