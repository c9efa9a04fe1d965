#!/bin/bash
# Interleaved library A/B: dr_bench live at 640x480, base vs new; writes JSON + time + load.
# usage: ab_lib.sh OUTDIR PAIRS FRAMES
out=$1; pairs=${2:-3}; frames=${3:-150}
mkdir -p $out
for r in $(seq 1 $pairs); do
  for b in base new; do
    uptime > $out/lib_${b}_r$r.load
    /usr/bin/time -f "%e %U %S" -o $out/lib_${b}_r$r.time \
      /tmp/h18/dr_bench_$b --scene=apartment --width=640 --height=480 --frames=$frames --methods=live \
      > $out/lib_${b}_r$r.json 2> $out/lib_${b}_r$r.err
    uptime >> $out/lib_${b}_r$r.load
  done
done
