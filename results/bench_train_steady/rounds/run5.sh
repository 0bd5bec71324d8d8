# issue 17, round 5 (final): learner benchmark against HEAD (.ref); the 1-agent step again; the
# largest population found to fit before (768 bf16 agents) under the new program, with its peak memory.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/f/learner $OUT/f/train $OUT/f/largest
python3 experiments/bench_learner.py --agents 128 1 --updates 100 --precision bf16 --reference .ref --out $OUT/f/learner 2>&1 | grep -E "agent-updates|Error" | tail -6
python3 experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --precision bf16 --reference .ref --name bench_train_1agent_b --out $OUT/f/train 2>&1 | grep -E "env-steps|Error" | tail -4
timeout 240 python3 experiments/bench_train.py --agents 768 --chunk 100 --repeats 1 --precision bf16 --name fit_bf16_768 --out $OUT/f/largest 2>&1 | grep -E "env-steps|Error|RESOURCE" | tail -3
python3 -c "import json; r=json.load(open('$OUT/f/largest/fit_bf16_768.json'))['rows'][0]; print('peak GiB', r['peak_gib'])" 2>&1 | tail -1
cd $OUT && tar czf final.tgz f && rm -rf f
