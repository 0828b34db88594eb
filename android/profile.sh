#!/usr/bin/env bash
# Profile every Android model of a pushed bundle on the phone with onnxruntime_perf_test, once per execution
# provider, pull the raw outputs back and turn them into a report in the `mosaic profile` schema.
#
#   android/profile.sh [--dry-run] [--serial S] [--device-dir DIR] [--providers cpu,xnnpack,nnapi,qnn]
#                      [--runs N] [--threads T] [--qnn-backend libQnnHtp.so] [--out DIR] BUNDLE
#
# Run android/push.sh first (with --perf-test/--ort-lib). cpu and xnnpack run <component>.ort; nnapi and qnn
# run <component>.with_runtime_opt.ort with session.enable_saved_runtime_optimizations=1. Inputs are random
# (-I), so the timings are real and the outputs are not checked. --dry-run prints the adb commands only.
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
# shellcheck source=android/common.sh
source "$HERE/common.sh"

usage() { sed -n '2,11p' "$0" | sed 's/^# \{0,1\}//'; }
PROVIDERS="cpu,xnnpack,nnapi,qnn"; RUNS=50; THREADS=4; OUT=""; BUNDLE=""; QNN_BACKEND="libQnnHtp.so"
while [[ $# -gt 0 ]]; do
  case "$1" in
    --dry-run) DRY_RUN=1; shift ;;
    --serial) SERIAL="${2:?--serial needs a value}"; shift 2 ;;
    --device-dir) DEVICE_DIR="${2:?--device-dir needs a value}"; shift 2 ;;
    --providers) PROVIDERS="${2:?--providers needs a list}"; shift 2 ;;
    --runs) RUNS="${2:?--runs needs a number}"; shift 2 ;;
    --threads) THREADS="${2:?--threads needs a number}"; shift 2 ;;
    --qnn-backend) QNN_BACKEND="${2:?--qnn-backend needs a library name}"; shift 2 ;;
    --out) OUT="${2:?--out needs a folder}"; shift 2 ;;
    -h|--help) usage; exit 0 ;;
    -*) die "unknown option $1 (see --help)" ;;
    *) set_bundle "$1"; shift ;;
  esac
done
check_bundle
[[ "$RUNS" =~ ^[1-9][0-9]*$ ]] || die "--runs must be a positive integer (got '$RUNS')"
[[ "$THREADS" =~ ^[1-9][0-9]*$ ]] || die "--threads must be a positive integer (got '$THREADS')"
OUT="${OUT:-$BUNDLE/android/profile}"
IFS=',' read -r -a provs <<< "$PROVIDERS"
for p in "${provs[@]}"; do
  case "$p" in cpu|xnnpack|nnapi|qnn) ;; *) die "--providers: unknown provider '$p' (cpu, xnnpack, nnapi, qnn)" ;; esac
done
need_adb
export DRY_RUN SERIAL

models="$(list_android_models "$BUNDLE")"
mkdir -p "$OUT/raw"
adb_run shell rm -rf "$DEVICE_DIR/results"
adb_run shell mkdir -p "$DEVICE_DIR/results"
if [[ "$DRY_RUN" != 1 ]]; then
  {
    echo "model=$("$ADB" ${SERIAL:+-s "$SERIAL"} shell getprop ro.product.model | tr -d '\r')"
    echo "soc=$("$ADB" ${SERIAL:+-s "$SERIAL"} shell getprop ro.soc.model | tr -d '\r')"
    echo "android=$("$ADB" ${SERIAL:+-s "$SERIAL"} shell getprop ro.build.version.release | tr -d '\r')"
  } > "$OUT/raw/device.txt"
fi
n=0
while IFS=$'\t' read -r role variant comp ort ro _prec; do
  for p in "${provs[@]}"; do
    model="$ort"; extra=""
    case "$p" in
      nnapi) [[ "$ro" != "-" ]] && model="$ro"; extra="-C 'session.enable_saved_runtime_optimizations|1'" ;;
      qnn) [[ "$ro" != "-" ]] && model="$ro"
           extra="-i 'backend_path|$QNN_BACKEND htp_performance_mode|burst' -C 'session.enable_saved_runtime_optimizations|1'" ;;
    esac
    tag="${role}__${variant}__${comp}__${p}"
    # One shell line on the phone; the exit code is appended so failures (provider missing) are reported.
    line="cd $DEVICE_DIR && LD_LIBRARY_PATH=$DEVICE_DIR ./onnxruntime_perf_test -e $p $extra -m times -r $RUNS"
    line+=" -x $THREADS -I -s $model > results/$tag.txt 2>&1; echo \"exit_code: \$?\" >> results/$tag.txt"
    adb_run shell "$line"
    n=$((n + 1))
  done
done <<< "$models"
adb_run pull "$DEVICE_DIR/results/." "$OUT/raw/"
if [[ "$DRY_RUN" == 1 ]]; then
  echo "# dry run: $n perf_test runs listed; then: ${PYTHON:-python3} $HERE/perf_report.py --bundle $BUNDLE --raw $OUT/raw --out $OUT" >&2
  exit 0
fi
"${PYTHON:-python3}" "$HERE/perf_report.py" --bundle "$BUNDLE" --raw "$OUT/raw" --out "$OUT"
