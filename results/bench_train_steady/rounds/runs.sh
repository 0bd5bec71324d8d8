#!/bin/bash
# The seven rounds of issue 17, each once a script of its own (rounds/run1.sh ... run7.sh), kept
# here verbatim as functions: `bash rounds/runs.sh run4` runs round 4 from the repository root.

run1() {
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
}

run2() {
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
}

run3() {
# issue 17, round 3: the committed steady program and compile options against HEAD (.ref).
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/r3 /tmp/dd
XLA_FLAGS="--xla_dump_to=/tmp/dd" python3 -c "import jax, jax.numpy as jnp; jax.jit(lambda x: x + 1)(jnp.ones(3))" 2>/dev/null
echo "== XLA's default command buffer types:"; grep -rho "xla_gpu_enable_command_buffer: [A-Z_]*" /tmp/dd | sort | uniq -c | head -20
T="python3 experiments/bench_train.py --out $OUT/r3 --reference .ref"
$T --agents 1 --chunk 1000 --repeats 5 --precision bf16 fp32 --name bench_train_1agent 2>&1 | grep -E "env-steps|Error|^\|" | tail -14
python3 experiments/bench_train.py --out $OUT/r3 --agents 1 --chunk 1000 --repeats 5 --precision bf16 --program general --name bench_train_1agent_general 2>&1 | grep -E "env-steps|Error" | tail -3
$T --agents 64 --chunk 300 --repeats 3 --precision bf16 fp32 --name bench_train_64 2>&1 | grep -E "env-steps|Error|^\|" | tail -14
}

run4() {
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
}

run5() {
# issue 17, round 5 (final): learner benchmark against HEAD (.ref); the 1-agent step again; the
# largest population found to fit before (768 bf16 agents) under the new program, with its peak memory.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/f/learner $OUT/f/train $OUT/f/largest
python3 experiments/bench_learner.py --agents 128 1 --updates 100 --precision bf16 --reference .ref --out $OUT/f/learner 2>&1 | grep -E "agent-updates|Error" | tail -6
python3 experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --precision bf16 --reference .ref --name bench_train_1agent_b --out $OUT/f/train 2>&1 | grep -E "env-steps|Error" | tail -4
timeout 240 python3 experiments/bench_train.py --agents 768 --chunk 100 --repeats 1 --precision bf16 --name fit_bf16_768 --out $OUT/f/largest 2>&1 | grep -E "env-steps|Error|RESOURCE" | tail -3
python3 -c "import json; r=json.load(open('$OUT/f/largest/fit_bf16_768.json'))['rows'][0]; print('peak GiB', r['peak_gib'])" 2>&1 | tail -1
cd $OUT && tar czf final.tgz f && rm -rf f
}

run6() {
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
}

run7() {
# issue 17, round 7 (final): this tree against HEAD (.ref), each in the same command.
# environment: MuJoCo 3.17.0, MuJoCo MJX and tyro installed beside jax 0.11.2 (CUDA)
mkdir -p $OUT/z/train $OUT/z/train_fp32 $OUT/z/learner
python3 experiments/bench_train.py --agents 1 32 64 --chunk 500 --repeats 3 --precision bf16 --reference .ref --out $OUT/z/train 2>&1 | grep -E "env-steps|Error" | tail -8
python3 experiments/bench_train.py --agents 1 --chunk 1000 --repeats 5 --precision fp32 --reference .ref --name bench_train_fp32_1agent --out $OUT/z/train_fp32 2>&1 | grep -E "env-steps|Error" | tail -4
python3 experiments/bench_learner.py --agents 128 1 --updates 100 --precision bf16 --reference .ref --out $OUT/z/learner 2>&1 | grep -E "agent-updates|Error" | tail -6
cd $OUT && tar czf z.tgz z && rm -rf z
}

"$@"
