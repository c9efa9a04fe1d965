#!/usr/bin/env bash
# ASan + UBSan run of the service, io, wire and client-store tests (issue 20 item 6) in its own
# build folder. Not part of `deploy/exoview test` (a sanitizer build of the server side takes
# ~20 min on 2 cores; the tests then run 2-5x slower):
#
#   tools/sanitize.sh [BUILD_DIR=build-asan] [CTEST_REGEX]
#
# A new BUILD_DIR is configured with -DEXOVIEW_SANITIZE=ON (gcc, RelWithDebInfo); an existing one
# is used as configured (e.g. build-fuzz of tools/fuzz/run_fuzz.sh, whose objects carry ASan +
# UBSan too). UBSan stops at the first error (-fno-sanitize-recover); ASan reports leaks at exit.
# Exit status: ctest's.
set -euo pipefail
root="$(cd "$(dirname "$0")/.." && pwd)"
bdir="${1:-$root/build-asan}"
regex="${2:-^(service_test|control_service_test|io_test|wire_test|client_store_test|store_sync_test|service_attacks_test|service_auth_test|service_bad_input_test|service_checkpoint_test|service_durable_test|service_udp_pose_test)$}"
case "$bdir" in /*) ;; *) bdir="$root/$bdir" ;; esac
if [ ! -f "$bdir/CMakeCache.txt" ]; then
  cmake -S "$root" -B "$bdir" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DEXOVIEW_SANITIZE=ON >/dev/null
fi
targets=$(echo "$regex" | tr -d '^$()' | tr '|' ' ')
extra="exoview_server exoview_uploader"
case "$regex" in *checkpoint*) extra="$extra exoview_viewer" ;; esac  # the viewer is a big build
cmake --build "$bdir" -j 2 --target $targets $extra >&2
export ASAN_OPTIONS="${ASAN_OPTIONS:-detect_leaks=1:abort_on_error=1:detect_stack_use_after_return=0}"
export UBSAN_OPTIONS="${UBSAN_OPTIONS:-print_stacktrace=1:halt_on_error=1}"
cd "$bdir"
ctest -R "$regex" --output-on-failure -j 1
