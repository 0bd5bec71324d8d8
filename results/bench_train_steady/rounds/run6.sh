# issue 17, round 6: where the latency-bound program stops paying: steady vs general program,
# one process each, with peak memory; the learner benchmark's per-call overhead at 1 agent.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/t
B="python3 experiments/bench_train.py --chunk 500 --repeats 3 --out $OUT/t"
for n in 16 32; do for p in steady general; do
  $B --agents $n --precision bf16 --program $p --name bf16_${n}_$p 2>&1 | grep -E "env-steps|Error" | tail -2
done; done
for p in steady general; do $B --agents 16 --precision fp32 --program $p --name fp32_16_$p 2>&1 | grep -E "env-steps|Error" | tail -2; done
python3 -c "
import json, glob
for f in sorted(glob.glob('$OUT/t/*.json')):
    r = json.load(open(f))['rows'][0]; print(f.split('/')[-1], round(r['agent_steps_per_s']), 'peak GiB %.2f' % r['peak_gib'])"
for u in 100 1000; do python3 experiments/bench_learner.py --agents 1 --updates $u --precision bf16 --out $OUT/t/l$u 2>&1 | grep -E "agent-updates|Error" | tail -1; done
cd $OUT && tar czf t.tgz t && rm -rf t
