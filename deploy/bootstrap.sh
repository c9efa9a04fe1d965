#!/usr/bin/env bash
# Installs the Debian 12 packages Exoview needs (only the missing ones), then configures and
# builds. Idempotent and quiet when nothing is missing. Used by `deploy/exoview demo|test`.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
BUILD_TYPE="${EXOVIEW_BUILD_TYPE:-Release}"

PKGS=(build-essential cmake ninja-build pkg-config
      libboost-dev libprotobuf-dev protobuf-compiler libgrpc++-dev protobuf-compiler-grpc
      libopencv-dev libvulkan-dev mesa-vulkan-drivers vulkan-tools vulkan-validationlayers
      glslang-tools glslang-dev libglm-dev libturbojpeg0-dev libpng-dev libceres-dev
      libgtest-dev libgmock-dev ccache libmeshoptimizer-dev
      nlohmann-json3-dev libcli11-dev libspdlog-dev python3-matplotlib python3-grpcio
      python3-grpc-tools python3-protobuf python3-numpy python3-pil python3-open3d
      libsdl2-dev libimgui-dev xvfb xdotool imagemagick chromium firefox-esr python3-websocket libssl-dev
      zlib1g-dev
      nats-server libnats-dev python3-kubernetes podman runc catatonit)

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  echo "[exoview] installing ${#missing[@]} missing package(s): ${missing[*]}" >&2
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq >/dev/null
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

if [ ! -f "$BUILD_DIR/build.ninja" ]; then
  cmake -S "$ROOT" -B "$BUILD_DIR" -G Ninja -DCMAKE_BUILD_TYPE="$BUILD_TYPE" ${EXOVIEW_CMAKE_ARGS:-} >/dev/null
fi
cmake --build "$BUILD_DIR" -j "$(nproc)" ${EXOVIEW_BUILD_TARGETS:+--target $EXOVIEW_BUILD_TARGETS}
