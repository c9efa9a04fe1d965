#!/bin/bash
# DR quality + keyframe CPU, 300 frames (the session-10 benchmark size, 320x240), keyframe crop off / on
out=$1; mkdir -p $out
for scene in apartment village; do
  for c in off on; do
    args=""; [ $c = on ] && args="--kf_crop_margin_px=32 --kf_crop_margin_rel=0.5"
    uptime > $out/crop_${scene}_$c.load
    /usr/bin/time -f "%e %U %S" -o $out/crop_${scene}_$c.time /tmp/h18/dr_bench_new --scene=$scene --frames=300 --methods=live $args > $out/crop_${scene}_$c.json 2>$out/crop_${scene}_$c.err
    uptime >> $out/crop_${scene}_$c.load
  done
done
