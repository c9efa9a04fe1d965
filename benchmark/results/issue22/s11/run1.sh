#!/bin/bash
# usage: run1.sh STREAM SEED STORES POLICIES OUT [extra]
s=$1; seed=$2; st=$3; pol=$4; out=$5; shift 5
nice -n 10 ${EVAL:-/work/wt_streams/build/server/eval/exoview_eval} --scene apartment --traj $s --frames 5000 --scene_seed $seed --test_seed $((10+seed)) --store $st --policies $pol --proxy gt --frame_w 160 --frame_h 120 --test_w 160 --test_h 120 --test_views 16 --test_poses near,scene "$@" > $out 2>$out.log
