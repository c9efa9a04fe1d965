#!/usr/bin/env bash
# The main job on the embedded default, end to end over gRPC on loopback:
#   1. exoview_synth writes the built-in synthetic scenes (frames, ground truth, report) to OUT/synth;
#   2. exoview_server starts (free port), exoview_uploader streams the synthetic apartment walk
#      (640x480 RGB-D at 30 Hz) while exoview_viewer follows the delta stream;
#   3. the viewer renders novel views along the walk path (Vulkan/lavapipe, else CPU reference),
#      writes PNG frames + MJPEG + per-frame timings, and MSSIM against ground truth;
#   4. OUT/report.json + OUT/report.md: MSSIM, bandwidth, latency; then everything stops cleanly
#      (SIGTERM -> graceful server shutdown; the script fails if any step fails).
# Options: --out DIR, --frames N (uploaded), --views N (rendered), --skip-synth.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
OUT="$ROOT/out/demo"
FRAMES=150
VIEWS=20
SKIP_SYNTH=0
while [ $# -gt 0 ]; do
  case "$1" in
    --out) OUT="$2"; shift 2;;
    --frames) FRAMES="$2"; shift 2;;
    --views) VIEWS="$2"; shift 2;;
    --skip-synth) SKIP_SYNTH=1; shift;;
    *) echo "unknown option $1" >&2; exit 2;;
  esac
done
mkdir -p "$OUT"
export VK_DRIVER_FILES="${VK_DRIVER_FILES:-/usr/share/vulkan/icd.d/lvp_icd.x86_64.json}"
export VK_ICD_FILENAMES="${VK_ICD_FILENAMES:-$VK_DRIVER_FILES}"

# 1. Synthetic scenes (60 frames per trajectory + 200 ground-truth test views per scene; pass more
#    with exoview_synth --frames N directly, thesis: 5000).
if [ "$SKIP_SYNTH" = 0 ]; then
  "$BUILD/common/synth/exoview_synth" --out "$OUT/synth" --frames 60 --test-poses 200
fi

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
"$BUILD/server/app/exoview_server" --listen=127.0.0.1:0 --port_file="$OUT/port" ${EXOVIEW_SERVER_ARGS:-} \
  > "$OUT/server.log" 2>&1 &
SERVER_PID=$!
for _ in $(seq 200); do [ -s "$OUT/port" ] && break; sleep 0.05; done
[ -s "$OUT/port" ] || { echo "server did not start:" >&2; cat "$OUT/server.log" >&2; exit 1; }
SERVER="127.0.0.1:$(cat "$OUT/port")"
echo "demo: server on $SERVER"

# 3. Viewer follows the stream during the upload, then renders along the walk path.
"$BUILD/client/viewer/exoview_viewer" --server="$SERVER" --until_frames="$FRAMES" \
  --delta_log="$OUT/viewer_deltas.txt" --state_json="$OUT/viewer_state.json" \
  --render_frames="$VIEWS" --width=640 --height=480 --out="$OUT/frames" \
  --path=synthetic:apartment:walk --max_seconds=600 > "$OUT/viewer.log" 2>&1 &
VIEWER_PID=$!
"$BUILD/client/uploader/exoview_uploader" --server="$SERVER" --synthetic=apartment \
  --trajectory=walk --frames="$FRAMES" --rate_hz=30 --progress \
  --stats_json="$OUT/upload.json" --send_log="$OUT/upload_sends.txt"
wait "$VIEWER_PID" || { echo "viewer failed:" >&2; cat "$OUT/viewer.log" >&2; exit 1; }
VIEWER_PID=""

# 4. Stop the server (graceful), then the report.
kill -TERM "$SERVER_PID"
wait "$SERVER_PID"
SERVER_PID=""

# Frame-to-delta latency: first delta per source frame (viewer) minus the frame's send time
# (uploader); both are CLOCK_MONOTONIC on this host.
LAT=$(awk 'NR==FNR { sent[$1] = $2; next }
           $1 != 0 && ($1 in sent) && !($1 in seen) { seen[$1] = 1; print ($2 - sent[$1]) / 1e6 }' \
        "$OUT/upload_sends.txt" "$OUT/viewer_deltas.txt" | sort -n)
N=$(printf '%s\n' "$LAT" | grep -c . || true)
pct() { [ "$N" -gt 0 ] && printf '%s\n' "$LAT" | awk -v n="$N" -v q="$1" 'NR == int(q * (n - 1) + 1.5) { print; exit }' || echo -1; }
P50=$(pct 0.5); P95=$(pct 0.95)
BYTES=$(awk '{ s += $3 } END { print s + 0 }' "$OUT/viewer_deltas.txt")
T0=$(head -n1 "$OUT/upload_sends.txt" | awk '{ print $2 }')
T1=$(tail -n1 "$OUT/viewer_deltas.txt" | awk '{ print $2 }')
SECS=$(awk -v a="$T0" -v b="$T1" 'BEGIN { print (b - a) / 1e9 }')
KBPS=$(awk -v b="$BYTES" -v s="$SECS" 'BEGIN { if (s > 0) print b * 8 / 1000 / s; else print 0 }')
VIEWER_REPORT=$(cat "$OUT/frames/viewer_report.json")
MSSIM=$(printf '%s' "$VIEWER_REPORT" | sed -n 's/.*"mssim": \([-0-9.e]*\).*/\1/p')
RENDER_MS=$(printf '%s' "$VIEWER_REPORT" | sed -n 's/.*"mean_render_ms": \([-0-9.e]*\).*/\1/p')
UP_FPS=$(sed -n 's/.*"fps": \([-0-9.e]*\).*/\1/p' "$OUT/upload.json")
RENDERER=$(printf '%s' "$VIEWER_REPORT" | sed -n 's/.*"renderer": "\([^"]*\)".*/\1/p')
cat > "$OUT/report.json" <<JSON
{"scene": "apartment", "uploaded_frames": $FRAMES, "rendered_views": $VIEWS,
 "mssim": $MSSIM, "renderer": "$RENDERER", "mean_render_ms": $RENDER_MS,
 "viewer_bytes": $BYTES, "viewer_kbit_per_s": $KBPS, "stream_seconds": $SECS,
 "frame_to_delta_p50_ms": $P50, "frame_to_delta_p95_ms": $P95, "frames_with_delta": $N,
 "upload": $(cat "$OUT/upload.json"),
 "viewer_store": $(cat "$OUT/viewer_state.json")}
JSON
cat > "$OUT/report.md" <<MD
# Exoview demo (synthetic apartment, server + uploader + viewer over gRPC on loopback)

| what | value |
|---|---|
| uploaded frames (640x480 RGB-D, rendered on the fly, asked 30 Hz) | $FRAMES at $UP_FPS fps |
| MSSIM of $VIEWS rendered views vs ground truth | $MSSIM |
| renderer, mean ms per 640x480 view | $RENDERER, $RENDER_MS |
| bytes received by the viewer | $BYTES ($KBPS kbit/s over $SECS s) |
| frame-to-delta latency p50 / p95 (ms) | $P50 / $P95 ($N frames produced deltas) |

Frames: \`frames/frame_*.png\`, \`frames/frames.mjpeg\`; per-frame timings and SSIM:
\`frames/viewer_report.json\`; upload ack statistics: \`upload.json\`; synthetic scenes: \`synth/\`.
MD
cat "$OUT/report.md"
