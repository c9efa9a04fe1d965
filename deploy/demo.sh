#!/usr/bin/env bash
# The main job on the embedded default, end to end over gRPC on loopback:
#   1. exoview_synth writes the built-in synthetic scenes (frames, ground truth, report) to OUT/synth;
#   2. exoview_server starts (free port) with a view store smaller than the stream (--store views),
#      exoview_uploader streams the synthetic apartment walk (640x480 RGB-D at 30 Hz, --frames
#      frames) while exoview_viewer follows the delta stream: the planner has to choose which
#      frames to keep;
#   3. the viewer saves its store (OUT/viewer.model), then renders novel views ON the walk path
#      (--views) and OFF it (--test-views per set: near the path, anywhere in the scene) with
#      Vulkan/lavapipe (else the CPU reference), each with its ground truth and SSIM;
#   4. exoview_export writes the viewer's store as PLY + TUM + COLMAP (OUT/export), read back by
#      tools/export/read_exports.py (numpy, Open3D);
#   5. tools/charts/demo_report.py writes OUT/report.json, report.md and report.html with charts and a
#      contact sheet (rendered | ground truth | error); everything stops cleanly (SIGTERM ->
#      graceful server shutdown; the script fails if any step fails).
# Options: --out DIR, --frames N (uploaded), --store N (views the server keeps), --views N
# (rendered on the path), --test-views N (per off-path set), --skip-synth.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
OUT="$ROOT/out/demo"
FRAMES=160
STORE=50
VIEWS=16
TEST_VIEWS=10
SKIP_SYNTH=0
while [ $# -gt 0 ]; do
  case "$1" in
    --out) OUT="$2"; shift 2;;
    --frames) FRAMES="$2"; shift 2;;
    --store) STORE="$2"; shift 2;;
    --views) VIEWS="$2"; shift 2;;
    --test-views) TEST_VIEWS="$2"; shift 2;;
    --skip-synth) SKIP_SYNTH=1; shift;;
    *) echo "unknown option $1" >&2; exit 2;;
  esac
done
mkdir -p "$OUT"
export VK_DRIVER_FILES="${VK_DRIVER_FILES:-/usr/share/vulkan/icd.d/lvp_icd.x86_64.json}"
export VK_ICD_FILENAMES="${VK_ICD_FILENAMES:-$VK_DRIVER_FILES}"
START_S=$(date +%s)
step() { echo "demo: $1 ($(( $(date +%s) - START_S )) s since the start)"; }

# 1. Synthetic scenes (30 frames per trajectory + 20 ground-truth test views per scene; pass more
#    with exoview_synth --frames N directly, thesis: 5000).
if [ "$SKIP_SYNTH" = 0 ]; then
  "$BUILD/common/synth/exoview_synth" --out "$OUT/synth" --frames 30 --test-poses 20
fi

step "synthetic scenes written"

# 2. Server on a free port; stopped on any exit.
SERVER_PID=""
VIEWER_PID=""
cleanup() {
  [ -n "$VIEWER_PID" ] && kill -TERM "$VIEWER_PID" 2>/dev/null || true
  if [ -n "$SERVER_PID" ] && kill -0 "$SERVER_PID" 2>/dev/null; then
    kill -TERM "$SERVER_PID"
    wait "$SERVER_PID" || true
  fi
}
trap cleanup EXIT
rm -f "$OUT/port"
# EXOVIEW_SERVER_ARGS: extra server flags (e.g. "--refinement=0" for an A/B run).
# shellcheck disable=SC2086
"$BUILD/server/app/exoview_server" --listen=127.0.0.1:0 --port_file="$OUT/port" \
  --max_views="$STORE" ${EXOVIEW_SERVER_ARGS:-} > "$OUT/server.log" 2>&1 &
SERVER_PID=$!
for _ in $(seq 200); do [ -s "$OUT/port" ] && break; sleep 0.05; done
[ -s "$OUT/port" ] || { echo "server did not start:" >&2; cat "$OUT/server.log" >&2; exit 1; }
SERVER="127.0.0.1:$(cat "$OUT/port")"
echo "demo: server on $SERVER (store $STORE views), streaming $FRAMES frames"

# 3. Viewer follows the stream during the upload, saves its store, then renders on and off the path.
rm -rf "$OUT/frames"
"$BUILD/client/viewer/exoview_viewer" --server="$SERVER" --until_frames="$FRAMES" \
  --delta_log="$OUT/viewer_deltas.txt" --state_json="$OUT/viewer_state.json" \
  --save_model="$OUT/viewer.model" \
  --render_frames="$VIEWS" --test_views="$TEST_VIEWS" --test_sets=near,scene --gt_png \
  --width=640 --height=480 --out="$OUT/frames" \
  --path=synthetic:apartment:walk --max_seconds=600 > "$OUT/viewer.log" 2>&1 &
VIEWER_PID=$!
"$BUILD/client/uploader/exoview_uploader" --server="$SERVER" --synthetic=apartment \
  --trajectory=walk --frames="$FRAMES" --rate_hz=30 --progress \
  --stats_json="$OUT/upload.json" --send_log="$OUT/upload_sends.txt"
wait "$VIEWER_PID" || { echo "viewer failed:" >&2; cat "$OUT/viewer.log" >&2; exit 1; }
VIEWER_PID=""
step "stream and novel views done"

# Stop the server (graceful).
kill -TERM "$SERVER_PID"
wait "$SERVER_PID"
SERVER_PID=""

# 4. Exports of the viewer's store: mesh.ply, trajectory.tum, colmap/.
rm -rf "$OUT/export"
"$BUILD/tools/export/exoview_export" --model "$OUT/viewer.model" --out "$OUT/export"
# ... read back by independent readers (numpy; Open3D when installed): counts, unit normals,
# COLMAP = inverse of TUM. Fails the demo when a check fails.
/usr/bin/python3 "$ROOT/tools/export/read_exports.py" "$OUT/export" > "$OUT/export/readback.json"

# 5. The report (JSON read with a parser; charts and contact sheet with matplotlib).
step "exported"
/usr/bin/python3 "$ROOT/tools/charts/demo_report.py" --out "$OUT" --frames "$FRAMES" --store "$STORE" \
  --wall_s "$(( $(date +%s) - START_S ))"
step "report written"
cat "$OUT/report.md"
