#!/bin/bash
# usage: run.sh STREAM SEED POLICIES OUT   (session 14, lead: the issue-22 protocol on the village)
s=$1; seed=$2; pol=$3; out=$4
root=$(cd "$(dirname "$0")/../../../../.." && pwd)
nice -n 10 "$root/build/server/eval/exoview_eval" --scene village --traj $s --frames 5000 --scene_seed $seed --test_seed $((10+seed)) --store 50,100,200 --policies $pol --proxy gt --frame_w 160 --frame_h 120 --test_w 160 --test_h 120 --test_views 16 --test_poses near,scene > $out 2>$out.log
