#!/bin/bash
# the optical-axis turn's ten folds paired with session 15's merged fold rows (default, every-N,
# min-distance, s = 0.5); run from the worktree root
t=$(mktemp -d)
for n in 0 1 2 3 4 5 6 7 8 9; do cat benchmark/results/issue22/s15/folds/merged_fold_$n.jsonl benchmark/results/issue22/s16/folds/fold_$n.jsonl > $t/fold_$n.jsonl; done
tools/paired_table.py --new online:dax=1 "$@" $t/fold_*.jsonl; rm -r $t
