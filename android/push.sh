#!/usr/bin/env bash
# Push a bundle's Android artifacts (.ort files, manifest, operator config) and onnxruntime_perf_test to a phone.
#
#   android/push.sh [--dry-run] [--serial S] [--device-dir DIR] [--perf-test BIN] [--ort-lib SO] BUNDLE
#
# --perf-test / --ort-lib: onnxruntime_perf_test and libonnxruntime.so built for arm64-v8a (see
# android/build_ort.sh); pushed next to the models when given. --dry-run prints the adb commands only.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=android/common.sh
source "$HERE/common.sh"

usage() { sed -n '2,8p' "$0" | sed 's/^# \{0,1\}//'; }
PERF_TEST=""; ORT_LIB=""; BUNDLE=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dry-run) DRY_RUN=1; shift ;;
    --serial) SERIAL="${2:?--serial needs a value}"; shift 2 ;;
    --device-dir) DEVICE_DIR="${2:?--device-dir needs a value}"; shift 2 ;;
    --perf-test) PERF_TEST="${2:?--perf-test needs a path}"; shift 2 ;;
    --ort-lib) ORT_LIB="${2:?--ort-lib needs a path}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) set_bundle "$1"; shift ;;
  esac
done
check_bundle
for f in "$PERF_TEST" "$ORT_LIB"; do
  [[ -z "$f" || -f "$f" ]] && continue
  # a dry run only prints the commands: the binaries need not be built yet
  if [[ "$DRY_RUN" == 1 ]]; then echo "# note: $f not found here (build it with android/build_ort.sh first)" >&2
  else die "$f: no such file (build it with android/build_ort.sh, or leave out the option)"; fi
done
need_adb
export DRY_RUN SERIAL

models="$(list_android_models "$BUNDLE")"
adb_run shell mkdir -p "$DEVICE_DIR/results"
adb_run push "$BUNDLE/manifest.json" "$DEVICE_DIR/manifest.json"
if [[ -f "$BUNDLE/android/required_operators.config" ]]; then
  adb_run push "$BUNDLE/android/required_operators.config" "$DEVICE_DIR/required_operators.config"
fi
while IFS=$'\t' read -r role variant comp ort ro _prec; do
  adb_run shell mkdir -p "$DEVICE_DIR/$(dirname "$ort")"
  adb_run push "$BUNDLE/$ort" "$DEVICE_DIR/$ort"
  if [[ "$ro" != "-" ]]; then adb_run push "$BUNDLE/$ro" "$DEVICE_DIR/$ro"; fi
  echo "# pushed $role/$variant/$comp" >&2
done <<< "$models"
if [[ -n "$PERF_TEST" ]]; then
  adb_run push "$PERF_TEST" "$DEVICE_DIR/onnxruntime_perf_test"
  adb_run shell chmod 755 "$DEVICE_DIR/onnxruntime_perf_test"
fi
if [[ -n "$ORT_LIB" ]]; then adb_run push "$ORT_LIB" "$DEVICE_DIR/libonnxruntime.so"; fi
echo "# bundle pushed to $DEVICE_DIR" >&2
