#!/usr/bin/env bash
# The main job on the embedded default: generate the built-in synthetic scenes and write frames,
# ground truth and a report. (The service issue turns this into server + uploader + viewer.)
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
OUT="$ROOT/out/demo"
while [ $# -gt 0 ]; do case "$1" in --out) OUT="$2"; shift 2;; *) echo "unknown option $1" >&2; exit 2;; esac; done
mkdir -p "$OUT"
exec "$BUILD/common/synth/exoview_synth" --out "$OUT"
