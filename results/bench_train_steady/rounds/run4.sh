# issue 17, round 4: the learner benchmark against HEAD (.ref); steady/general parity at paper sizes.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/r4/learner $OUT/r4/parity
python3 experiments/bench_learner.py --agents 128 1 --updates 100 --precision bf16 --reference .ref --out $OUT/r4/learner 2>&1 | grep -E "agent-updates|Error|^\|" | tail -16
python3 experiments/steady_parity.py --agents 4 --chunks 3 --precision bf16 --name steady_parity_bf16 --out $OUT/r4/parity 2>&1 | grep -E "^\||Error" | tail -9
python3 experiments/steady_parity.py --agents 4 --chunks 3 --precision fp32 --name steady_parity_fp32 --out $OUT/r4/parity 2>&1 | grep -E "^\||Error" | tail -9
B="experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --precision bf16 --out $OUT/r4"
(cd .var && PYTHONPATH=$PWD:$PYTHONPATH python3 $B --name unroll2 2>&1 | grep -E "env-steps|Error" | tail -2)
python3 $B --name tree 2>&1 | grep -E "env-steps|Error" | tail -2
(cd .var && PYTHONPATH=$PWD:$PYTHONPATH python3 $B --name unroll2_b 2>&1 | grep -E "env-steps|Error" | tail -2)
python3 $B --name tree_b 2>&1 | grep -E "env-steps|Error" | tail -2
