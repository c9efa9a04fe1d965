#!/bin/bash
# usage: run.sh SCENE STREAM SEED POLICIES OUT [extra exoview_eval flags]   (session 15: the issue-22
# protocol, both scenes, with --per_view 1; 5 000 frames, gt proxy, 160x120, 16 + 16 test poses)
scene=$1; s=$2; seed=$3; pol=$4; out=$5; shift 5
root=$(cd "$(dirname "$0")/../../../../.." && pwd)
nice -n 10 "$root/build/server/eval/exoview_eval" --scene $scene --traj $s --frames 5000 --scene_seed $seed --test_seed $((10+seed)) --store ${STORES:-50,100,200} --policies $pol --proxy gt --frame_w 160 --frame_h 120 --test_w 160 --test_h 120 --test_views 16 --test_poses ${POSES:-near,scene} --per_view 1 "$@" > $out 2>$out.log
