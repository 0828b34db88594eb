#!/usr/bin/env bash
# Build a reduced-operator ONNX Runtime for Android (arm64-v8a) that runs exactly the bundle's .ort models,
# plus onnxruntime_perf_test for android/profile.sh.
#
#   android/build_ort.sh [--dry-run] [--abi arm64-v8a] [--api 27] [--qnn] [--no-nnapi] [--no-xnnpack]
#                        --ort-src DIR BUNDLE
#
# Needs an onnxruntime source checkout (same release as the converter: see the bundle manifest's
# android.onnxruntime_version), ANDROID_HOME (SDK), ANDROID_NDK_HOME (NDK) and, with --qnn, QNN_SDK_ROOT.
# The operator list is BUNDLE/android/required_operators.config written by `mosaic export --target android`.
# --dry-run prints the build line only (this is all that can be checked without the SDK/NDK).
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=android/common.sh
source "$HERE/common.sh"

usage() { sed -n '2,12p' "$0" | sed 's/^# \{0,1\}//'; }
ABI="arm64-v8a"; API=27; QNN=0; NNAPI=1; XNNPACK=1; ORT_SRC=""; BUNDLE=""
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dry-run) DRY_RUN=1; shift ;;
    --abi) ABI="${2:?--abi needs a value}"; shift 2 ;;
    --api) API="${2:?--api needs a value}"; shift 2 ;;
    --qnn) QNN=1; shift ;;
    --no-nnapi) NNAPI=0; shift ;;
    --no-xnnpack) XNNPACK=0; shift ;;
    --ort-src) ORT_SRC="${2:?--ort-src needs a folder}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) set_bundle "$1"; shift ;;
  esac
done
[[ -n "$BUNDLE" ]] || { usage; die "BUNDLE folder missing"; }
CONFIG="$(cd "$BUNDLE" && pwd)/android/required_operators.config"
[[ -f "$CONFIG" ]] || die "$CONFIG not found: run \`mosaic export --target android --out $BUNDLE\` first"
[[ "$API" =~ ^[0-9]+$ ]] || die "--api must be a number"
[[ -n "$ORT_SRC" ]] || die "--ort-src DIR (an onnxruntime source checkout) is required"

# SDK/NDK paths expanded here; unset (a dry run on a machine without them): a "$NAME" the shell expands when the
# printed line is run where they are set
for v in ANDROID_HOME ANDROID_NDK_HOME; do
  [[ -n "${!v:-}" || "$DRY_RUN" != 1 ]] || echo "# note: $v is not set here: set it before running the line" >&2
done
cmd=(./build.sh --config MinSizeRel --android
     --android_sdk_path "${ANDROID_HOME:-\$ANDROID_HOME}" --android_ndk_path "${ANDROID_NDK_HOME:-\$ANDROID_NDK_HOME}"
     --android_abi "$ABI" --android_api "$API"
     --minimal_build extended --disable_ml_ops --include_ops_by_config "$CONFIG"
     --build_shared_lib --build_java --skip_tests --parallel)
[[ "$NNAPI" == 1 ]] && cmd+=(--use_nnapi)
[[ "$XNNPACK" == 1 ]] && cmd+=(--use_xnnpack)
[[ "$QNN" == 1 ]] && cmd+=(--use_qnn --qnn_home "${QNN_SDK_ROOT:-\$QNN_SDK_ROOT}")
[[ "$QNN" != 1 || -n "${QNN_SDK_ROOT:-}" || "$DRY_RUN" != 1 ]] || echo "# note: QNN_SDK_ROOT is not set here" >&2

if [[ "$DRY_RUN" == 1 ]]; then
  echo "cd $ORT_SRC"
  show "${cmd[@]}"
  echo "# outputs: build/Android/MinSizeRel/libonnxruntime.so and onnxruntime_perf_test (push them with android/push.sh)" >&2
  exit 0
fi
[[ -x "$ORT_SRC/build.sh" ]] || die "$ORT_SRC/build.sh not found: --ort-src must be an onnxruntime checkout"
[[ -n "${ANDROID_HOME:-}" && -n "${ANDROID_NDK_HOME:-}" ]] || die "set ANDROID_HOME and ANDROID_NDK_HOME"
cd "$ORT_SRC"
"${cmd[@]}"
