#!/bin/bash
# queue3.sh: after village drone seed 2 (queue2's first job), the handhelds (one seed each) and then with a turn-weight cap probe
# (online:mpr=7: 7 m/rad, the m sessions 15-16 found good on the village drone; under the server's
# rule every other stream has d_max < 7 m, so a cap at 7 m/rad changes only the outdoor drone).
here=$(cd "$(dirname "$0")" && pwd); cd "$here"
. ./jobs.sh
job apartment handheld 1 online,min_distance,every_n_online,reservoir,keyframe,every_n dev/apartment_handheld_s1.jsonl
job village handheld 1 online,min_distance,keyframe,every_n dev/village_handheld_s1.jsonl
job village drone 3 online,min_distance,online:mpr=7,online:drs=0.5 dev/village_drone_s3.jsonl
