#!/usr/bin/env bash
# Run the MosaicThinker container on a Jetson with the GPU, a bundle and a persistent TensorRT cache.
#
#   jetson/run.sh [--dry-run] [--image TAG] [--cache DIR] [--data DIR] [--build-engines | --arm64-check SHARED]
#                 BUNDLE [-- MOSAIC ARGS...]
#
# The bundle is mounted read-only at /bundle (where `mosaic export --target jetson` points the provider
# options), the cache folder at /cache (engines, timing cache, EP-context models: built on the first run, reused
# after). --data mounts a folder of videos/frames at /data. --build-engines runs the bundle's
# jetson/build_engines.sh (trtexec) instead of mosaic. --arm64-check SHARED runs jetson/arm64_check.sh --native
# in the container (the ../shared folder at /shared; result in CACHE/arm64). --dry-run prints the docker command.
set -euo pipefail

die() { echo "error: $*" >&2; exit 2; }
usage() { sed -n '2,10p' "$0" | sed 's/^# \{0,1\}//'; }
IMAGE="mosaicthinker:jp6"; CACHE="${HOME:-/tmp}/.cache/mosaicthinker-trt"; DATA=""; DRY=0; ENGINES=0; BUNDLE=""
CHECK=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dry-run) DRY=1; shift ;;
    --image) IMAGE="${2:?--image needs a tag}"; shift 2 ;;
    --cache) CACHE="${2:?--cache needs a folder}"; shift 2 ;;
    --data) DATA="${2:?--data needs a folder}"; shift 2 ;;
    --build-engines) ENGINES=1; shift ;;
    --arm64-check) CHECK="${2:?--arm64-check needs the ../shared folder}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    --) shift; break ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) [[ -z "$BUNDLE" ]] || die "one BUNDLE only (mosaic arguments go after --)"; BUNDLE="$1"; shift ;;
  esac
done
[[ -n "$BUNDLE" ]] || { usage; die "BUNDLE folder missing"; }
[[ -f "$BUNDLE/manifest.json" ]] || die "$BUNDLE/manifest.json not found (not a bundle folder)"
if [[ "$ENGINES" == 1 && ! -f "$BUNDLE/jetson/build_engines.sh" ]]; then
  die "$BUNDLE/jetson/build_engines.sh missing: run \`mosaic export ... --target jetson --out $BUNDLE\` first"
fi
BUNDLE="$(cd "$BUNDLE" && pwd)"

cmd=(docker run --rm --runtime nvidia --network host --ipc host
     -v "$BUNDLE:/bundle:ro" -v "$CACHE:/cache")
[[ -n "$DATA" ]] && cmd+=(-v "$(cd "$DATA" && pwd):/data:ro")
if [[ -n "$CHECK" ]]; then
  [[ -d "$CHECK/data" && -d "$CHECK/models" ]] || die "--arm64-check $CHECK: not the ../shared folder (data/, models/)"
  cmd+=(-v "$(cd "$CHECK" && pwd):/shared:ro" -e BUNDLE=/bundle -e MOSAIC_SHARED=/shared
        --entrypoint /opt/mosaicthinker/jetson/arm64_check.sh "$IMAGE" --native /cache/arm64)
elif [[ "$ENGINES" == 1 ]]; then
  cmd+=(--entrypoint bash "$IMAGE" /bundle/jetson/build_engines.sh)
else
  [[ $# -gt 0 ]] || set -- bundle verify /bundle
  cmd+=("$IMAGE" "$@")
fi
if [[ "$DRY" == 1 ]]; then
  printf '%q ' "${cmd[@]}"; echo
  exit 0
fi
command -v docker >/dev/null 2>&1 || die "docker not found"
mkdir -p "$CACHE"
exec "${cmd[@]}"
