#!/bin/bash
# Interleaved server A/B: dr_live_bench 640x480 150 frames, the same client, base vs new server.
# usage: ab_server.sh OUTDIR PAIRS [extra dr_live_bench args]
out=$1; pairs=${2:-3}; shift 2
mkdir -p $out
for r in $(seq 1 $pairs); do
  for b in base new; do
    uptime > $out/srv_${b}_r$r.load
    /usr/bin/time -f "%e %U %S" -o $out/srv_${b}_r$r.time \
      /tmp/h18/dr_live_bench --width=640 --height=480 --frames=150 \
      --server_bin=/tmp/h18/exoview_server_$b "$@" > $out/srv_${b}_r$r.json 2> $out/srv_${b}_r$r.err
    uptime >> $out/srv_${b}_r$r.load
  done
done
