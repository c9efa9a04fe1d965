#!/bin/bash
# queue2.sh: the rest of session 17's runs after the village drone seed 1 (time: ~25 min wall per
# village seed with 7 policies at load 8-9, so seeds 2-3 and the handhelds get fewer policies).
here=$(cd "$(dirname "$0")" && pwd); cd "$here"
. ./jobs.sh
job village drone 2 online,min_distance,online:drs=0.5 dev/village_drone_s2.jsonl
job apartment handheld 1 online,min_distance,every_n_online,reservoir,keyframe,every_n dev/apartment_handheld_s1.jsonl
job village drone 3 online,min_distance,online:drs=0.5 dev/village_drone_s3.jsonl
job village handheld 1 online,min_distance,keyframe,every_n dev/village_handheld_s1.jsonl
