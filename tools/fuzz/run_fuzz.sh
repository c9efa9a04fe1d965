#!/usr/bin/env bash
# Bounded libFuzzer run of the fuzz targets in fuzz/ (issue 20 item 6), with ASan + UBSan, in its
# own clang build folder. Not part of `deploy/exoview test` (it takes minutes):
#
#   tools/fuzz/run_fuzz.sh [SECONDS_PER_TARGET=60] [BUILD_DIR=build-fuzz]
#   FUZZ_TARGETS="delta checkpoint" tools/fuzz/run_fuzz.sh 60    # some targets only
#
# Seeds: fuzz/corpus/<target>/ (committed; written by fuzz/make_seeds.cc when empty). Prints one
# JSON line per target: executions, seconds, crashes (files named crash-* / leak-* / timeout-*
# under BUILD_DIR/fuzz/artifacts_<target>/), new corpus entries. Exit 1 if any target crashed.
set -euo pipefail
root="$(cd "$(dirname "$0")/../.." && pwd)"
secs="${1:-60}"
bdir="${2:-$root/build-fuzz}"
command -v clang++ >/dev/null || { echo "run_fuzz: clang++ is not installed" >&2; exit 1; }
if [ ! -f "$bdir/build.ninja" ]; then
  cmake -S "$root" -B "$bdir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo \
    -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ -DEXOVIEW_FUZZ=ON >/dev/null
fi
cmake --build "$bdir" -j "$(nproc)" --target jpeg_fuzz depth_fuzz frame_fuzz delta_fuzz \
  checkpoint_fuzz make_seeds >&2
corpus="$root/fuzz/corpus"
if [ -z "$(ls -A "$corpus/jpeg" 2>/dev/null)" ] || [ -z "$(ls -A "$corpus/delta" 2>/dev/null)" ]; then
  "$bdir/fuzz/make_seeds" "$corpus" >&2
fi
status=0
for t in ${FUZZ_TARGETS:-jpeg depth frame delta checkpoint}; do
  work="$bdir/fuzz/work_$t"
  art="$bdir/fuzz/artifacts_$t"
  mkdir -p "$work" "$art"
  cp -n "$corpus/$t"/* "$work"/ 2>/dev/null || true
  before=$(ls "$work" | wc -l)
  log="$bdir/fuzz/$t.log"
  start=$(date +%s)
  "$bdir/fuzz/${t}_fuzz" -max_total_time="$secs" -rss_limit_mb=2048 -timeout=10 \
    -print_final_stats=1 -artifact_prefix="$art/" "$work" >"$log" 2>&1 || true
  end=$(date +%s)
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "$log" | grep -o '[0-9]*$' || echo 0)
  crashes=$(ls "$art" | grep -c -E '^(crash|leak|timeout|oom)-' || true)
  after=$(ls "$work" | wc -l)
  python3 -c 'import json,sys; print(json.dumps({"target": sys.argv[1] + "_fuzz", "seconds": int(sys.argv[2]), "executions": int(sys.argv[3] or 0), "crashes": int(sys.argv[4]), "corpus_before": int(sys.argv[5]), "corpus_after": int(sys.argv[6]), "log": sys.argv[7]}))' \
    "$t" "$((end - start))" "$runs" "$crashes" "$before" "$after" "$log"
  [ "$crashes" -eq 0 ] || status=1
done
exit $status
