# issue 17: this tree against the commit before (a copy in .ref), bf16, 1 agent, two processes each, alternating;
# run from the repository root with the package importable and OUT set to a folder.
mkdir -p $OUT/ab
for i in 1 2; do
  python3 experiments/bench_train.py --agents 1 --precision bf16 --chunk 1000 --repeats 5 --name tree_$i --out $OUT/ab 2>&1 | grep "env-steps"
  (cd .ref && PYTHONPATH=$PWD:$PYTHONPATH python3 experiments/bench_train.py --agents 1 --precision bf16 --chunk 1000 --repeats 5 --name ref_$i --out $OUT/ab 2>&1 | grep "env-steps")
done
rm -f $OUT/ab/*.md
