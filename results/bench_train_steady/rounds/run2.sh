# issue 17, round 2: command-buffer scheduling (CONCURRENT) and whole-loop graphs (+WHILE) on the
# steady program, the general program and HEAD (.ref); an unrolled-block variant (.var).
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/r2
B="experiments/bench_train.py --chunk 1000 --repeats 5 --precision bf16 --out $OUT/r2"
b() { dir=$1; name=$2; shift 2; echo "== $name [$dir] XLA_FLAGS=$XLA_FLAGS $*"; (cd $dir && PYTHONPATH=$PWD:$PYTHONPATH timeout 170 python3 $B --name $name "$@" 2>&1 | grep -E "env-steps|Error" | tail -2); }
CC=--xla_gpu_command_buffer_scheduling_mode=CONCURRENT
WH=--xla_gpu_enable_command_buffer=+WHILE
export XLA_FLAGS="$CC $WH"; b . steady_cc_wh --agents 1
export XLA_FLAGS="$CC"; b . general_cc --agents 1 --program general
export XLA_FLAGS="$CC"; b .ref ref_cc --agents 1
export XLA_FLAGS="$CC"; b . steady_cc --agents 1
export XLA_FLAGS=; b .var unroll --agents 1
export XLA_FLAGS="$CC $WH"; b .var unroll_cc_wh --agents 1
export XLA_FLAGS=; b .ref ref --agents 1
export XLA_FLAGS="$CC $WH"; b . steady_cc_wh_64 --agents 64 --chunk 300 --repeats 3
export XLA_FLAGS=; b .ref ref_64 --agents 64 --chunk 300 --repeats 3
rm -f $OUT/r2/*.md
