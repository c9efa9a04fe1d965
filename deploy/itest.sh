#!/usr/bin/env bash
# The containerized integration test (issue 21 item 4; what an operator runs): `podman kube play`
# of the local overlay of deploy/k8s (deploy/k8s/local: 3 NATS JetStream nodes, the modeling
# server with its checkpoint volume, two relays), then the uploader streaming the synthetic scene
# and 3 viewers following the relays. Faults while the upload runs: kill relay A, kill the
# server (it restarts from its volume: checkpoint + frame journal, reconciled with the stream),
# kill a NATS node. At the end every viewer's model digest must equal the server's, and every
# frame the uploader got a durable ack for must be in the server's model exactly once ("durable
# frames lost" = durable-acked sequences the server's applied-frame ledger does not hold).
# Prints a JSON summary and that line; exit 0 = digests equal and durable frames lost = 0.
#   deploy/itest.sh [--keep]        (deploy/exoview itest; --keep leaves the pods up)
# Needs podman + runc (apt-get install podman runc) and the images (deploy/images.sh builds them
# when missing). Ports 24222-28224 and 25051-25062 on loopback must be free.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
KEEP=0
[ "${1:-}" = "--keep" ] && KEEP=1
export CONTAINERS_CONF="${CONTAINERS_CONF:-$ROOT/deploy/containers.conf}"
D=/tmp/exoview-itest
LOCAL="$ROOT/deploy/k8s/local"
HEALTH="$BUILD_DIR/tools/health/exoview_health"
VIEWER="$BUILD_DIR/client/viewer/exoview_viewer"
log() { echo "[itest $(date +%T)] $*" >&2; }

command -v podman >/dev/null || { echo "SKIP itest: podman is not installed (apt-get install podman runc)" >&2; exit 77; }
# One itest per machine at a time: container names, loopback ports, /tmp/exoview-itest and the
# image tags are fixed, and a second run beside this one (another checkout's test suite) tears
# down and overwrites this one's pods and images. A second run waits here. (ctest's podman_itest
# takes the same lock around images.sh + this script and sets EXOVIEW_ITEST_LOCKED.)
if [ -z "${EXOVIEW_ITEST_LOCKED:-}" ]; then
  exec 9>/tmp/exoview-itest.lock
  flock 9
fi
[ "$(id -u)" = 0 ] || { echo "SKIP itest: needs root podman (host network, chown of the volumes)" >&2; exit 77; }
[ -x "$HEALTH" ] && [ -x "$VIEWER" ] || { echo "itest: build exoview_health and exoview_viewer first" >&2; exit 1; }
for img in server relay uploader viewer nats; do
  podman image exists "localhost/exoview-$img:latest" || { log "building images"; "$ROOT/deploy/images.sh" >&2; break; }
done

down() {
  podman kube down "$LOCAL/itest-clients.yaml" >/dev/null 2>&1 || true
  podman kube down "$LOCAL/itest-infra.yaml" >/dev/null 2>&1 || true
}
down
rm -rf "$D"
mkdir -p "$D"/{server,uploader,viewer-0,viewer-1,viewer-2}
for i in 0 1 2; do
  mkdir -p "$D/nats-$i"
  routes=""
  for j in 0 1 2; do [ "$j" != "$i" ] && routes+="${routes:+, }nats://127.0.0.1:$((26222 + j))"; done
  cat > "$D/nats-$i.conf" <<EOF
server_name: n$i
listen: 127.0.0.1:$((24222 + i))
http: 127.0.0.1:$((28222 + i))
max_payload: 8MB
jetstream { store_dir: /data }
cluster { name: exoview-itest, listen: 127.0.0.1:$((26222 + i)), routes: [ $routes ] }
EOF
done
chown -R 10001:10001 "$D"
[ "$KEEP" = 1 ] || trap down EXIT

T0=$(date +%s)
log "kube play: NATS x3, server, relay A, relay B"
podman kube play "$LOCAL/itest-infra.yaml" >/dev/null 2>"$D/play-infra.err" || { cat "$D/play-infra.err" >&2; exit 1; }
wait_healthy() {  # port, seconds
  local t=0
  until "$HEALTH" "127.0.0.1:$1" >/dev/null 2>&1; do
    sleep 1; t=$((t + 1))
    if [ "$t" -ge "$2" ]; then log "127.0.0.1:$1 not SERVING after $2 s"; return 1; fi
  done
  return 0
}
wait_healthy 25051 120
wait_healthy 25061 60
wait_healthy 25062 60
T_UP=$(( $(date +%s) - T0 ))
log "up in ${T_UP} s; kube play: uploader (150 frames at 10 Hz), 3 viewers"
podman kube play "$LOCAL/itest-clients.yaml" >/dev/null 2>"$D/play-clients.err" || { cat "$D/play-clients.err" >&2; exit 1; }

# A crash is SIGKILL of the container's process from outside (podman applies no restart policy to
# a container stopped by `podman kill`/`podman stop`; a crashed one is restarted).
crash() { kill -9 "$(podman inspect "$1" --format '{{.State.Pid}}')"; faults+=("$1"); }
faults=()
sleep 4; log "fault: crash relay A";  crash exoview-relay-a-relay
sleep 4; log "fault: crash the server"; crash exoview-server-server
sleep 4; log "fault: crash NATS node 2"; crash nats-2-nats

# The upload ends (after the server kill the uploader reconnects and resends what was not acked).
for _ in $(seq 1 300); do
  st="$(podman inspect exoview-uploader-uploader --format '{{.State.Status}} {{.State.ExitCode}}' 2>/dev/null || echo gone)"
  [ "$st" = "exited 0" ] && break
  sleep 1
done
log "uploader: $st"
wait_healthy 25051 120
# The server settled: its version unchanged over 3 s (read through a one-shot viewer).
server_state() { "$VIEWER" --server=127.0.0.1:25051 --state_json="$D/server.json" --renderer=cpu --no_png \
                   --out="$D/server_view" --max_seconds=60 >/dev/null 2>&1; \
                 python3 -c "import json;d=json.load(open('$D/server.json'));print(d['server_version'],d['server_digest'],d['views'],json.dumps(d.get('server_uploaders',[]),sort_keys=True).replace(' ',''))"; }
prev=""; cur="$(server_state)"
while [ "$cur" != "$prev" ]; do prev="$cur"; sleep 3; cur="$(server_state)"; done
read -r SV SD SVIEWS _ <<<"$cur"
log "server settled at version $SV digest $SD ($SVIEWS views)"
# Viewers catch up, then stop (SIGTERM: they write their state).
sleep 5
for v in 0 1 2; do podman kill --signal TERM "exoview-viewer-$v-viewer" >/dev/null 2>&1 || true; done
sleep 3
equal=0; results=()
for v in 0 1 2; do
  f="$D/viewer-$v/state.json"
  if [ -f "$f" ]; then
    read -r vv vd <<<"$(python3 -c "import json;d=json.load(open('$f'));print(d['version'],d['digest'])")"
    restarts="$(podman inspect "exoview-viewer-$v-viewer" --format '{{.RestartCount}}' 2>/dev/null || echo '?')"
    resumes="$(podman logs "exoview-viewer-$v-viewer" 2>&1 | grep -c 'resuming' || true)"
  else
    vv=0; vd=0; restarts='?'; resumes=0
  fi
  [ "$vd" = "$SD" ] && equal=$((equal + 1))
  results+=("{\"viewer\": $v, \"version\": $vv, \"digest\": $vd, \"restarts\": \"$restarts\", \"stream_resumes\": $resumes}")
done
srv_restarts="$(podman inspect exoview-server-server --format '{{.RestartCount}}' 2>/dev/null || echo '?')"
replayed="$(grep -h 'replayed versions' "$D"/server/*.log 2>/dev/null | tail -1 || true)"
# Durable frames lost: every sequence the uploader got a durable ack for (its --durable_log) must
# be in the server's applied-frame ledger for that uploader (sequences 1..applied_max_sequence,
# each once: applied_frames = applied_max_sequence, double_applied = 0). Lost = durable-acked
# sequences above the ledger's highest + holes in the ledger.
read -r DURABLE LOST TWICE <<<"$(python3 - "$D/uploader/durable.log" "$D/server.json" <<'PY'
import json, sys
acked = set()
try:
    acked = {int(l) for l in open(sys.argv[1]) if l.strip()}
except FileNotFoundError:
    pass
led = [u for u in json.load(open(sys.argv[2])).get("server_uploaders", [])
       if u["uploader"].endswith("itest-uploader")]
top = led[0]["applied_max_sequence"] if led else 0
frames = led[0]["applied_frames"] if led else 0
twice = led[0]["double_applied"] if led else 0
lost = sum(1 for q in acked if q > top) + max(0, top - frames)
print(len(acked), lost, twice)
PY
)"
printf '{"faults": ["%s"], "server": {"version": %s, "digest": %s, "views": %s, "restarts": "%s"}, "viewers": [%s], "viewers_equal": %d, "viewers_total": 3, "durable_acked": %d, "durable_frames_lost": %d, "frames_applied_twice": %d, "up_s": %d, "total_s": %d}\n' \
  "$(IFS=,; echo "${faults[*]}" | sed 's/,/", "/g')" "$SV" "$SD" "$SVIEWS" "$srv_restarts" \
  "$(IFS=,; echo "${results[*]}")" "$equal" "$DURABLE" "$LOST" "$TWICE" "$T_UP" "$(( $(date +%s) - T0 ))"
podman logs exoview-server-server 2>&1 | grep -E "restored|replayed|abandoned|delta log: JetStream" | tail -6 >&2 || true
echo "durable frames lost = $LOST (of $DURABLE acked durable; applied twice: $TWICE); viewers digest-equal: $equal of 3"
[ "$equal" = 3 ] && [ "$LOST" = 0 ] && [ "$TWICE" = 0 ] && [ "$DURABLE" -gt 0 ]
