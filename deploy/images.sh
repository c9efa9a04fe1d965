#!/usr/bin/env bash
# Builds the Exoview container images with podman, FROM scratch (no image registry is needed):
# each image's root file system is the built binaries + exactly the shared libraries they load
# (ldd), from this Debian 12 machine's packages, + /etc/passwd with the non-root user exoview
# (uid 10001). exoview-viewer also carries the Vulkan loader and Mesa's lavapipe ICD (software
# Vulkan, headless). Server and relay carry exoview_health (grpc.health.v1 check) for the image
# HEALTHCHECK and the Kubernetes exec probes. Run the containers with --read-only: nothing in
# the image is written (the server's checkpoints go to a volume at /data, temp files to /tmp).
#   deploy/images.sh [--tag TAG] [--out DIR]      (deploy/exoview images)
# Prints one JSON line per image (name, size bytes, build seconds) and a total.
set -euo pipefail
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
BUILD_DIR="${EXOVIEW_BUILD_DIR:-$ROOT/build}"
TAG=latest
OUT="${TMPDIR:-/tmp}/exoview-images"
while (($#)); do
  case "$1" in
    --tag) TAG="$2"; shift 2 ;;
    --out) OUT="$2"; shift 2 ;;
    *) echo "usage: deploy/images.sh [--tag TAG] [--out DIR]" >&2; exit 2 ;;
  esac
done

command -v podman >/dev/null || {
  echo "[images] podman is not installed: apt-get install podman runc" >&2; exit 1; }
# podman in this kind of sandbox cannot raise rlimits (runc: "error setting rlimit type 7"):
# fixed ulimits in a containers.conf make every podman command here work (TOOLCHAIN.md).
export CONTAINERS_CONF="${CONTAINERS_CONF:-$ROOT/deploy/containers.conf}"

bin() {  # path of a built binary
  local p
  p="$(find "$BUILD_DIR" -type f -name "$1" -perm -u+x -not -path "*/CMakeFiles/*" | head -1)"
  [ -n "$p" ] || { echo "[images] $1 is not built (cmake --build $BUILD_DIR --target $1)" >&2; exit 1; }
  echo "$p"
}

# copy FILE into ROOTFS at the same path, with every shared library it loads.
add_with_libs() {
  local rootfs="$1" file="$2" dest="${3:-$2}"
  mkdir -p "$rootfs$(dirname "$dest")"
  cp -L "$file" "$rootfs$dest"
  ldd "$file" | awk '/=> \//{print $3} /^[ \t]*\/.*ld-linux/{print $1}' | while read -r lib; do
    [ -e "$rootfs$lib" ] && continue
    mkdir -p "$rootfs$(dirname "$lib")"
    cp -L "$lib" "$rootfs$lib"
  done
}

base_rootfs() {
  local rootfs="$1"
  rm -rf "$rootfs"
  mkdir -p "$rootfs"/{etc,tmp,data,usr/bin}
  chmod 1777 "$rootfs/tmp"
  echo 'exoview:x:10001:10001:exoview:/data:/nonexistent' > "$rootfs/etc/passwd"
  echo 'exoview:x:10001:' > "$rootfs/etc/group"
  echo 'hosts: files dns' > "$rootfs/etc/nsswitch.conf"
  # glibc resolves names through libnss_* (dlopened, not in ldd): the pods resolve service names.
  for l in /lib/x86_64-linux-gnu/libnss_dns.so.2 /lib/x86_64-linux-gnu/libnss_files.so.2 \
           /lib/x86_64-linux-gnu/libresolv.so.2; do
    [ -e "$l" ] && { mkdir -p "$rootfs$(dirname "$l")"; cp -L "$l" "$rootfs$l"; }
  done
}

build_image() {  # name, rootfs, entrypoint, healthcheck-port (or "")
  local name="$1" rootfs="$2" entry="$3" health="$4"
  find "$rootfs/usr/bin" -type f -exec strip --strip-unneeded {} + 2>/dev/null || true
  {
    echo "FROM scratch"
    echo "COPY rootfs/ /"
    echo "USER 10001:10001"
    echo "WORKDIR /data"
    echo "ENV VK_DRIVER_FILES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"
    echo "ENV VK_ICD_FILENAMES=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json"
    [ -n "$health" ] && echo "HEALTHCHECK --interval=10s --timeout=3s CMD [\"/usr/bin/exoview_health\", \"127.0.0.1:$health\"]"
    echo "ENTRYPOINT [\"$entry\"]"
    echo "LABEL org.opencontainers.image.title=\"$name\" org.opencontainers.image.source=\"exoview $(git -C "$ROOT" describe --always --dirty 2>/dev/null || echo unknown)\""
  } > "$(dirname "$rootfs")/Containerfile"
  local t0 t1
  t0=$(date +%s.%N)
  podman build -q --format docker -t "localhost/$name:$TAG" "$(dirname "$rootfs")" >/dev/null
  t1=$(date +%s.%N)
  local size
  size=$(podman image inspect "localhost/$name:$TAG" --format '{{.Size}}')
  # The image this build replaced under the tag is now dangling: drop it (only dangling images with
  # this title), or every test run leaves ~240 MB behind until the disk fills (session 15: 2 274
  # images, 4.9 GB left, and NATS JetStream refused the itest's stream: "insufficient storage").
  podman image prune -f --filter "label=org.opencontainers.image.title=$name" >/dev/null 2>&1 || true
  printf '{"image": "localhost/%s:%s", "size_bytes": %s, "build_s": %.1f}\n' "$name" "$TAG" "$size" \
    "$(echo "$t1 - $t0" | bc -l)"
}

T0=$(date +%s.%N)
mkdir -p "$OUT"
HEALTH="$(bin exoview_health)"

# exoview-server
R="$OUT/server/rootfs"; base_rootfs "$R"
add_with_libs "$R" "$(bin exoview_server)" /usr/bin/exoview_server
add_with_libs "$R" "$HEALTH" /usr/bin/exoview_health
build_image exoview-server "$R" /usr/bin/exoview_server 50051

# exoview-relay
R="$OUT/relay/rootfs"; base_rootfs "$R"
add_with_libs "$R" "$(bin exoview_relay)" /usr/bin/exoview_relay
add_with_libs "$R" "$HEALTH" /usr/bin/exoview_health
build_image exoview-relay "$R" /usr/bin/exoview_relay 50061

# exoview-uploader
R="$OUT/uploader/rootfs"; base_rootfs "$R"
add_with_libs "$R" "$(bin exoview_uploader)" /usr/bin/exoview_uploader
build_image exoview-uploader "$R" /usr/bin/exoview_uploader ""

# exoview-viewer: headless, Vulkan on Mesa's lavapipe (the loader finds the ICD by the JSON).
R="$OUT/viewer/rootfs"; base_rootfs "$R"
add_with_libs "$R" "$(bin exoview_viewer)" /usr/bin/exoview_viewer
ICD=/usr/share/vulkan/icd.d/lvp_icd.x86_64.json
[ -f "$ICD" ] || { echo "[images] $ICD missing: apt-get install mesa-vulkan-drivers" >&2; exit 1; }
mkdir -p "$R/usr/share/vulkan/icd.d"
cp "$ICD" "$R$ICD"
LVP="$(sed -n 's/.*"library_path": *"\([^"]*\)".*/\1/p' "$ICD")"
add_with_libs "$R" "$LVP"
build_image exoview-viewer "$R" /usr/bin/exoview_viewer ""

# exoview-nats: Debian's nats-server (JetStream) for the manifests and the podman itest.
if command -v nats-server >/dev/null; then
  R="$OUT/nats/rootfs"; base_rootfs "$R"
  add_with_libs "$R" "$(command -v nats-server)" /usr/bin/nats-server
  build_image exoview-nats "$R" /usr/bin/nats-server ""
else
  echo "[images] nats-server not installed: no exoview-nats image (apt-get install nats-server)" >&2
fi

T1=$(date +%s.%N)
printf '{"images": %s, "total_build_s": %.1f}\n' "$(ls -d "$OUT"/*/rootfs | wc -l)" "$(echo "$T1 - $T0" | bc -l)"
