#!/bin/bash
# usage: run_policies.sh BUILD OUTDIR FOLDS "POLICIES" "STORES"
B=$1; OUT=$2; FOLDS=$3; POL=$4; STORES=$5
mkdir -p $OUT
cd /work/wt_15
for S in $STORES; do for P in $POL; do
  echo "$(date -u +%H:%M:%S) start $P store $S folds $FOLDS load $(cut -d' ' -f1 /proc/loadavg)" >> $OUT/progress.log
  nice -n 5 /usr/bin/python3 tools/product_eval.py --build $B --folds $FOLDS --no_open3d --width 320 --height 240 \
    --server_arg=--max_views=$S --server_arg=--admission_block=1 --policy $P \
    --out $OUT/product_eval_store${S}_${P}.jsonl > $OUT/log_${S}_${P}.txt 2>&1
  echo "$(date -u +%H:%M:%S) done $P store $S rc=$?" >> $OUT/progress.log
done; done
