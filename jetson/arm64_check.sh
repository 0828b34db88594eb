#!/usr/bin/env bash
# The light runtime on ARM64 Linux: build an aarch64 environment, run `mosaic demo` and one `mosaic ask` on a
# bundle of the shared models there, compare the answers with the x86 run.
#
#   jetson/arm64_check.sh OUT             # x86 host: aarch64 under qemu-user (proot), needs root for apt-get
#   jetson/arm64_check.sh --native OUT    # on an aarch64 device (jetson/Dockerfile's check): no emulation
#
# Emulated (x86 host, Debian 12): apt-get installs qemu-user-static + proot, Debian's arm64 python3.11 packages
# are downloaded (`dpkg --add-architecture arm64`, `apt-get download`) and unpacked into OUT/rootfs, the
# runtime's aarch64 wheels come from PyPI (`pip install --target --platform manylinux_2_28_aarch64
# --only-binary=:all:`, versions pinned in .ci/constraints.txt), the project's own wheel is built from the
# working tree. The bundle (`mosaic export shared-models`, without the AGPL instance segmenter) and the x86
# answers come from the x86 venv (PYTHON, default .venv/bin/python). onnxruntime crashes under qemu unless it
# reads an ARM /proc/cpuinfo, so proot binds a Cortex-A78 one there.
# Native (--native, aarch64): the runtime installed on the device (`mosaic` on PATH), the bundle given by
# BUNDLE, the x86 answers by X86_REF (default benchmarks/results/arm64_check.json, written by an emulated run).
# The demo and the ask use the same small settings everywhere (DEMO_ARGS, ASK_ARGS below).
#
# Writes OUT/arm64_check.json (details: wheels per platform, answers on both sides) and prints its summary as
# the LAST line: {"machine", "demo_score", "ask_status", "answers_equal_x86", "seconds"}. Exit 0 when machine is
# aarch64, the demo's mean score >= 0.9 and every answer equals x86's; 1 otherwise; 2 on bad usage.
# Slow (minutes under emulation): not in the default CI lane (docs/deployment.md, "ARM64").
set -euo pipefail

die() { echo "error: $*" >&2; exit 2; }
NATIVE=0
if [[ "${1:-}" == "--native" ]]; then NATIVE=1; shift; fi
[[ $# -eq 1 ]] || die "usage: jetson/arm64_check.sh [--native] OUT"
START=$(date +%s)
REPO="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
mkdir -p "$1"
OUT="$(cd "$1" && pwd)"
SHARED="$(cd "${MOSAIC_SHARED:-$REPO/../shared}" && pwd)" || die "../shared not found (set MOSAIC_SHARED)"
ROOM="$SHARED/data/7scenes-redkitchen"
QUESTION="How many chairs are in the room?"
DEMO_ARGS=(--duration 8 --keyframes 6)
ASK_ARGS=(--depth sensor --keyframes 8 --answerer map)
ROLES="depth,detector,embedder,segmenter"
log() { echo "[arm64_check $(date +%H:%M:%S)] $*" >&2; }

# -- the aarch64 environment (emulated) -----------------------------------------------------------------------
ROOTFS="$OUT/rootfs"
SITE=/opt/mosaic-site
DEBS=(libc6 libgcc-s1 libstdc++6 libgomp1 gcc-12-base zlib1g libbz2-1.0 liblzma5 libexpat1 libffi8 libssl3
      libsqlite3-0 libncursesw6 libtinfo6 libreadline8 libuuid1 libcrypt1 libdb5.3 libnsl2 libtirpc3
      libgssapi-krb5-2 libk5crypto3 libkrb5-3 libkrb5support0 libkeyutils1 libcom-err2 python3.11-minimal
      libpython3.11-minimal libpython3.11-stdlib python3.11)
PLATFORMS=(--platform manylinux_2_28_aarch64 --platform manylinux_2_17_aarch64 --platform manylinux2014_aarch64)

host_tools() {
  if command -v qemu-aarch64-static >/dev/null && command -v proot >/dev/null \
     && dpkg --print-foreign-architectures | grep -qx arm64; then
    return
  fi
  [[ "$(id -u)" == 0 ]] || die "qemu-user-static/proot/arm64 multiarch missing and not root: run as root once"
  log "apt-get: qemu-user-static, proot, arm64 package lists"
  dpkg --add-architecture arm64
  apt-get update -qq
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq qemu-user-static proot >/dev/null
}

build_rootfs() {
  if [[ -x "$ROOTFS/usr/bin/python3.11" ]]; then return; fi
  log "Debian arm64 python3.11 -> $ROOTFS"
  mkdir -p "$OUT/debs" "$ROOTFS/tmp"
  (cd "$OUT/debs" && apt-get download -qq "${DEBS[@]/%/:arm64}" 2>/dev/null)
  for d in "$OUT"/debs/*.deb; do dpkg -x "$d" "$ROOTFS"; done
  chmod 1777 "$ROOTFS/tmp"
  # an ARM cpuinfo for onnxruntime's cpuinfo library (it segfaults on the host's x86 one under qemu)
  printf 'processor\t: %s\nBogoMIPS\t: 50.00\nFeatures\t: fp asimd evtstrm aes pmull sha1 sha2 crc32 atomics fphp asimdhp cpuid asimdrdm lrcpc dcpop asimddp\nCPU implementer\t: 0x41\nCPU architecture: 8\nCPU variant\t: 0x1\nCPU part\t: 0xd41\nCPU revision\t: 1\n\n' 0 1 > "$OUT/cpuinfo"
}

install_wheels() {
  if [[ -f "$ROOTFS$SITE/.done" ]]; then return; fi
  log "aarch64 wheels from PyPI (pinned by .ci/constraints.txt) -> $ROOTFS$SITE"
  grep -iE '^(numpy|scipy|opencv-python-headless|onnxruntime|pillow|psutil|tokenizers|tqdm|tomli_w)==' \
    "$REPO/.ci/constraints.txt" > "$OUT/requirements-arm64.txt"
  "$PY" -m pip download -q -d "$OUT/wheels-arm64" "${PLATFORMS[@]}" --python-version 3.11 --implementation cp \
    --abi cp311 --only-binary=:all: -r "$OUT/requirements-arm64.txt" 2>&1 | grep -v '^WARNING: Location' || true
  "$PY" -m pip install -q --no-index --find-links "$OUT/wheels-arm64" --target "$ROOTFS$SITE" "${PLATFORMS[@]}" \
    --python-version 3.11 --implementation cp --abi cp311 --only-binary=:all: -r "$OUT/requirements-arm64.txt"
  # the project itself (pure Python) from the working tree's tracked files
  rm -rf "$OUT/src" && mkdir -p "$OUT/src"
  (cd "$REPO" && git ls-files -z | tar --null -T - -cf - | tar -xf - -C "$OUT/src")
  "$PY" -m pip wheel -q --no-deps --no-build-isolation -w "$OUT/wheels-project" "$OUT/src"
  "$PY" -m pip install -q --no-deps --upgrade --target "$ROOTFS$SITE" "$OUT"/wheels-project/mosaicthinker-*.whl
  touch "$ROOTFS$SITE/.done"
}

arm() {  # run the aarch64 python in the rootfs: arm ARGS...
  env -i PATH=/usr/bin:/bin HOME=/tmp PYTHONPATH="$SITE" OMP_NUM_THREADS=1 LANG=C.UTF-8 \
    proot -q qemu-aarch64-static -r "$ROOTFS" -b /dev -b /proc -b /sys -b "$OUT/cpuinfo:/proc/cpuinfo" \
    -b "$OUT" -b "$SHARED" -w /tmp /usr/bin/python3.11 "$@"
}

MOSAIC_PY='import sys; from mosaicthinker.runtime.cli import main; sys.exit(main(sys.argv[1:]))'

run_pair() {  # run_pair SIDE RUNNER...: demo and ask into OUT/SIDE/
  local side=$1; shift
  rm -rf "${OUT:?}/$side"; mkdir -p "$OUT/$side"
  log "$side: mosaic demo ${DEMO_ARGS[*]}"
  "$@" demo "${DEMO_ARGS[@]}" --out "$OUT/$side/demo" --json > "$OUT/$side/demo.json"
  log "$side: mosaic ask $ROOM \"$QUESTION\" ${ASK_ARGS[*]}"
  "$@" ask "$ROOM" "$QUESTION" --bundle "$BUNDLE" "${ASK_ARGS[@]}" --out "$OUT/$side/ask" --json \
    > "$OUT/$side/ask.json"
}

x86_mosaic() { OMP_NUM_THREADS=1 "$PY" -c "$MOSAIC_PY" "$@"; }
arm_mosaic() { arm -c "$MOSAIC_PY" "$@"; }
native_mosaic() { OMP_NUM_THREADS=1 mosaic "$@"; }

if [[ "$NATIVE" == 1 ]]; then
  [[ "$(uname -m)" == aarch64 ]] || die "--native runs on an aarch64 machine (this is $(uname -m))"
  BUNDLE="${BUNDLE:?--native needs BUNDLE=<bundle of the shared models, roles $ROLES>}"
  X86_REF="${X86_REF:-$REPO/benchmarks/results/arm64_check.json}"
  [[ -f "$X86_REF" ]] || die "X86_REF=$X86_REF not found (the arm64_check.json of an emulated run)"
  PY=python3
  run_pair arm64 native_mosaic
else
  PY="${PYTHON:-$REPO/.venv/bin/python}"
  [[ -x "$PY" ]] || die "PYTHON=$PY: no x86 python with the project (and its export extra) installed"
  X86_REF=""
  host_tools
  build_rootfs
  install_wheels
  BUNDLE="$OUT/bundle"
  if [[ ! -f "$BUNDLE/manifest.json" ]]; then
    log "bundle of the shared models ($ROLES) -> $BUNDLE"
    x86_mosaic export shared-models --source "dir:$SHARED/models" --set "roles=$ROLES" --out "$BUNDLE" >/dev/null
  fi
  run_pair x86 x86_mosaic
  T0=$(date +%s)
  run_pair arm64 arm_mosaic
  log "emulated demo + ask: $(( $(date +%s) - T0 )) s"
fi

"$PY" "$REPO/jetson/arm64_compare.py" --out "$OUT" --start "$START" ${X86_REF:+--x86-ref "$X86_REF"}
