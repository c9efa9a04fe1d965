#!/bin/bash
# usage: run.sh SCENE STREAM SEED POLICIES OUT [extra exoview_eval flags]   (session 17)
# The issue-22 protocol of sessions 13-16 (5 000 frames, gt proxy, 160x120, stores 50/100/200,
# --per_view 1) with two changes: --scale server (d_max, sigma and the cell size from the stream's
# first frame by core::ChooseSceneSetup, as the server derives them; sessions 13-16 ran
# --scale bounds, d_max = 0.15 x the scene diagonal) and 64 + 64 test poses (16 + 16 before; the
# first 16 of the 64 are the old 16: the pose sampler draws them in sequence).
# EVAL=path of the exoview_eval copy (default /tmp/h22_exoview_eval); VIEWS, STORES, POSES override.
scene=$1; s=$2; seed=$3; pol=$4; out=$5; shift 5
eval=${EVAL:-/tmp/h22_exoview_eval}
/usr/bin/time -f "%e s wall, %U+%S s cpu" nice -n 10 "$eval" --scene $scene --traj $s --frames 5000 \
  --scene_seed $seed --test_seed $((10+seed)) --store ${STORES:-50,100,200} --policies $pol \
  --proxy gt --frame_w 160 --frame_h 120 --test_w 160 --test_h 120 --test_views ${VIEWS:-64} \
  --test_poses ${POSES:-near,scene} --per_view 1 --scale ${SCALE:-server} "$@" > $out 2>$out.log
