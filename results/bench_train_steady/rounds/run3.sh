# issue 17, round 3: the committed steady program and compile options against HEAD (.ref).
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/r3 /tmp/dd
XLA_FLAGS="--xla_dump_to=/tmp/dd" python3 -c "import jax, jax.numpy as jnp; jax.jit(lambda x: x + 1)(jnp.ones(3))" 2>/dev/null
echo "== XLA's default command buffer types:"; grep -rho "xla_gpu_enable_command_buffer: [A-Z_]*" /tmp/dd | sort | uniq -c | head -20
T="python3 experiments/bench_train.py --out $OUT/r3 --reference .ref"
$T --agents 1 --chunk 1000 --repeats 5 --precision bf16 fp32 --name bench_train_1agent 2>&1 | grep -E "env-steps|Error|^\|" | tail -14
python3 experiments/bench_train.py --out $OUT/r3 --agents 1 --chunk 1000 --repeats 5 --precision bf16 --program general --name bench_train_1agent_general 2>&1 | grep -E "env-steps|Error" | tail -3
$T --agents 64 --chunk 300 --repeats 3 --precision bf16 fp32 --name bench_train_64 2>&1 | grep -E "env-steps|Error|^\|" | tail -14
