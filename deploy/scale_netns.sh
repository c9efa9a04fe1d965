#!/usr/bin/env bash
# Multi-host run on one machine (issue 21 item 5): a viewer in its own network namespace behind a
# veth link shaped by tbf (default 20 Mbit/s, host -> viewer), a relay on the host side, the server
# and NATS on loopback. Measures the time for the viewer to join and hold the model and its
# steady bandwidth while frames arrive. Needs root (ip netns, tc) and nats-server.
#   deploy/scale_netns.sh [RATE]         e.g. 20mbit (default), 5mbit
# Prints one JSON line.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
B="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
RATE="${1:-20mbit}"
NS=exo_scale_v
D="$(mktemp -d /tmp/exoview_netns_XXXXXX)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  ip netns del "$NS" 2>/dev/null || true
  ip link del exo_sh 2>/dev/null || true
}
trap cleanup EXIT
cleanup
ip netns add "$NS"
ip link add exo_sh type veth peer name exo_sn
ip link set exo_sn netns "$NS"
ip addr add 10.78.0.1/24 dev exo_sh && ip link set exo_sh up
ip netns exec "$NS" ip addr add 10.78.0.2/24 dev exo_sn
ip netns exec "$NS" ip link set exo_sn up
ip netns exec "$NS" ip link set lo up
tc qdisc add dev exo_sh root tbf rate "$RATE" burst 32kbit latency 400ms   # host -> viewer

echo 'max_payload: 8MB' > "$D/nats.conf"
nats-server -c "$D/nats.conf" -js -a 127.0.0.1 -p 34222 -sd "$D/js" >"$D/nats.log" 2>&1 & pids+=($!)
sleep 1
"$B/server/app/exoview_server" --listen=127.0.0.1:0 --port_file="$D/sport" --delta_log=jetstream \
  --nats_url=nats://127.0.0.1:34222 --scene=netns --voxel_size_m=0.08 --mesh_every_n_frames=5 \
  --fuse_depth_downscale=2 --admission_block=true >"$D/server.log" 2>&1 & pids+=($!)
"$B/server/relay/exoview_relay" --listen=10.78.0.1:35061 --allow_insecure_remote=true \
  --nats_url=nats://127.0.0.1:34222 --scene=netns >"$D/relay.log" 2>&1 & pids+=($!)
for _ in $(seq 100); do [ -f "$D/sport" ] && break; sleep 0.1; done
S="127.0.0.1:$(cat "$D/sport")"
up() { "$B/client/uploader/exoview_uploader" --server="$S" --synthetic=apartment --trajectory=walk \
         --first="$1" --frames="$(( $1 + $2 ))" --width=320 --height=240 --rate_hz=10 >>"$D/up.log" 2>&1; }
up 0 30
sleep 2
until "$B/tools/health/exoview_health" 10.78.0.1:35061 >/dev/null 2>&1; do sleep 0.2; done
V="$B/client/viewer/exoview_viewer"
# Join: from nothing to the model, through the shaped link.
ip netns exec "$NS" "$V" --server=10.78.0.1:35061 --journal="$D/v.journal" --state_json="$D/join.json" \
  --renderer=cpu --no_png --out="$D/vout" --settle_ms=300 >"$D/join.log" 2>&1
# Steady: follow while 30 more frames arrive at 10 Hz.
ip netns exec "$NS" "$V" --server=10.78.0.1:35061 --journal="$D/v.journal" --state_json="$D/steady.json" \
  --renderer=cpu --no_png --out="$D/vout" --follow --max_seconds=120 >"$D/steady.log" 2>&1 & VP=$!
t0=$(date +%s.%N)
up 30 30
# The server settled: its version unchanged over 1 s (read through a one-shot viewer).
server_version() { "$V" --server="$S" --state_json="$D/srv.json" --renderer=cpu --no_png --out="$D/sout" \
                     >/dev/null 2>&1; python3 -c "import json;print(json.load(open('$D/srv.json'))['server_version'])"; }
prev=""; sv="$(server_version)"
while [ "$sv" != "$prev" ]; do prev="$sv"; sleep 1; sv="$(server_version)"; done
# Wait for the relay to hold the server's version, then give the viewer the link time to drain.
for _ in $(seq 600); do
  "$V" --server=10.78.0.1:35061 --state_json="$D/rel.json" --renderer=cpu --no_png --out="$D/rout" >/dev/null 2>&1 || true
  [ "$(python3 -c "import json;print(json.load(open('$D/rel.json'))['server_version'])")" = "$sv" ] && break
  sleep 0.5
done
t1=$(date +%s.%N)
sleep 3
kill -TERM "$VP"; wait "$VP" || true
python3 - "$D" "$RATE" "$t0" "$t1" <<'EOF'
import json, sys
d, rate, t0, t1 = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
j = json.load(open(f"{d}/join.json"))
s = json.load(open(f"{d}/steady.json"))
srv = json.load(open(f"{d}/srv.json"))
print(json.dumps({
    "link": rate,
    "join_s": round(j["sync_s"], 2),
    "join_MB": round(j["bytes"] / 1e6, 2),
    "join_Mbit_s": round(j["bytes"] * 8 / 1e6 / j["sync_s"], 1),
    "join_views": j["views"],
    "steady_MB": round(s["bytes"] / 1e6, 2),
    "steady_window_s": round(t1 - t0, 1),
    "steady_Mbit_s": round(s["bytes"] * 8 / 1e6 / (t1 - t0), 2),
    "viewer_digest_equal": s["digest"] == srv["server_digest"],
    "viewer_version": s["version"], "server_version": srv["server_version"],
}))
EOF
