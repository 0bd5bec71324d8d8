# issue 17, round 7 (final): this tree against HEAD (.ref), each in the same command.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/z/train $OUT/z/train_fp32 $OUT/z/learner
python3 experiments/bench_train.py --agents 1 32 64 --chunk 500 --repeats 3 --precision bf16 --reference .ref --out $OUT/z/train 2>&1 | grep -E "env-steps|Error" | tail -8
python3 experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --precision fp32 --reference .ref --name bench_train_fp32_1agent --out $OUT/z/train_fp32 2>&1 | grep -E "env-steps|Error" | tail -4
python3 experiments/bench_learner.py --agents 128 1 --updates 100 --precision bf16 --reference .ref --out $OUT/z/learner 2>&1 | grep -E "agent-updates|Error" | tail -6
cd $OUT && tar czf z.tgz z && rm -rf z
