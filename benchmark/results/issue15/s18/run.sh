#!/bin/bash
# usage: run.sh BUILD TAG FOLDS STORE POLICY [extra server args...]
B=$1; TAG=$2; FOLDS=$3; S=$4; P=$5; shift 5
OUT=/work/s18/runs; mkdir -p $OUT/keep_$TAG
EXTRA=""; for a in "$@"; do EXTRA="$EXTRA --server_arg=$a"; done
echo "$(date -u +%H:%M:%S) start $TAG folds $FOLDS store $S $P $* load $(cut -d' ' -f1 /proc/loadavg)" >> $OUT/progress.log
cd /work/main
nice -n 5 /usr/bin/python3 tools/product_eval.py --build $B --folds $FOLDS --no_open3d --width 320 --height 240 \
  --server_arg=--max_views=$S --server_arg=--admission_block=1 $EXTRA --policy $P --keep $OUT/keep_$TAG \
  --out $OUT/$TAG.jsonl > $OUT/log_$TAG.txt 2>&1
echo "$(date -u +%H:%M:%S) done $TAG rc=$?" >> $OUT/progress.log
