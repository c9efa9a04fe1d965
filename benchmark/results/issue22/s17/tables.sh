#!/bin/bash
# tables.sh: session 17's tables -> summary.md (all from dev/*.jsonl; runs are deterministic).
here=$(cd "$(dirname "$0")" && pwd); cd "$here"
{
echo "# Session 17 (issue 22): --scale server, 64 + 64 test poses"
echo; echo "## Planner - each policy (64 views)"
for f in apartment_drone apartment_handheld village_drone village_handheld; do
  ls dev/${f}_s*.jsonl >/dev/null 2>&1 && ./summary.py dev/${f}_s*.jsonl
done
echo; echo "## The same runs, first 16 test views only (the sessions 13-16 test poses)"
for f in apartment_drone village_drone; do ./summary.py --views 16 dev/${f}_s*.jsonl; done
echo; echo "## Cause: nearest stored camera centre / turn / coverage per policy (64 views)"
./summary.py --cause dev/village_drone_s*.jsonl dev/apartment_drone_s*.jsonl
echo; echo "## Protocol gap: --scale bounds (sessions 15-16 rows, 16 views) vs --scale server"
for x in "apartment/drone_merged_s1 apartment_drone_s1" "village/drone_merged_s1 village_drone_s1" \
         "village/drone_merged_s2 village_drone_s2" "village/drone_merged_s3 village_drone_s3" \
         "apartment/handheld_merged_s1 apartment_handheld_s1" "village/handheld_merged_s1 village_handheld_s1"; do
  set -- $x; [ -s dev/$2.jsonl ] && { echo; ./gap.py ../s15/$1.jsonl dev/$2.jsonl; }
done
} > summary.md
