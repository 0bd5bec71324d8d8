# issue 17: XLA flags against the 1-agent full training step (bench_train.py), one process per
# setting; run from the repository root with the package importable and OUT set to a folder.
mkdir -p $OUT/sweep
CB="--xla_gpu_enable_command_buffer=FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,WHILE,CONDITIONAL"
run() { name=$1; shift; echo "== $name: XLA_FLAGS=$XLA_FLAGS $*"; python3 experiments/bench_train.py --chunk 300 --repeats 3 --name $name --out $OUT/sweep "$@" 2>&1 | grep -v "^W0\|^I0\|^wrote" | tail -8; rm -f $OUT/sweep/$name.md; }
export XLA_FLAGS=; run v0_default --agents 1 --precision bf16 fp32
export XLA_FLAGS="$CB"; run v1_cb_while_cond --agents 1 64 --precision bf16 fp32
export XLA_FLAGS="$CB --xla_gpu_graph_min_graph_size=1"; run v2_cb_min1 --agents 1 --precision bf16 fp32
export XLA_FLAGS="--xla_gpu_enable_cublaslt=true"; run v3_cublaslt --agents 1 64 --precision bf16
