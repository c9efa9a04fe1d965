#!/usr/bin/env bash
# The main job on the embedded default: generate the built-in synthetic scenes and write frames,
# ground truth and a report. (The service issue turns this into server + uploader + viewer.)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
OUT="$ROOT/out/demo"
while [ $# -gt 0 ]; do case "$1" in --out) OUT="$2"; shift 2;; *) echo "unknown option $1" >&2; exit 2;; esac; done
mkdir -p "$OUT"
# 60 frames per trajectory + 200 ground-truth test views per scene keeps the default run short;
# pass more with exoview_synth --frames N directly (thesis: 5000).
exec "$BUILD/common/synth/exoview_synth" --out "$OUT" --frames 60 --test-poses 200
