#!/bin/bash
# queue4.sh: replaces queue3.sh's tail (a village drone seed costs ~18 min wall whatever the
# policies: no time left for seed 3 and the online:mpr=7 probe): the village handheld seed 1, then
# the apartment streams' seed 2.
here=$(cd "$(dirname "$0")" && pwd); cd "$here"
. ./jobs.sh
job village handheld 1 online,min_distance,keyframe,every_n dev/village_handheld_s1.jsonl
job apartment handheld 2 $ALL dev/apartment_handheld_s2.jsonl
job apartment drone 2 $ALL dev/apartment_drone_s2.jsonl
