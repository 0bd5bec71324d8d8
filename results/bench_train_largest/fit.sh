# issue 17: the largest paper-size training population that fits on one H100 (full step, default memory settings)
# run from the repository root with the package importable and OUT set to an empty folder
export PYTHONPATH=$PWD PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader
T0=$SECONDS
try() {  # try PRECISION N -> rc
  echo "######## $1 $2 agents"
  timeout 160 python3 experiments/bench_train.py --agents $2 --chunk 50 --repeats 1 --precision $1 --name fit_$1_$2 --out $OUT > $OUT/fit_$1_$2.log 2>&1
  rc=$?; echo "rc=$rc at $((SECONDS-T0)) s"
  grep -E "env-steps/s|RESOURCE_EXHAUSTED|ut of memory" $OUT/fit_$1_$2.log | cut -c1-300 | head -2
  return $rc
}
lo=512; hi=1024
try bf16 $lo || lo=0
while [ $lo -gt 0 ] && [ $((hi - lo)) -gt 128 ] && [ $((SECONDS-T0)) -lt 380 ]; do
  mid=$(( (lo + hi) / 2 ))
  if try bf16 $mid; then lo=$mid; else hi=$mid; fi
done
echo "== bf16: fits $lo, fails $hi"
try fp32 $lo || echo "== fp32 does not fit at $lo"
rm -f $OUT/*.md
