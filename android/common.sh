#!/usr/bin/env bash
# Shared helpers for the android/ scripts (sourced, not run). Needs bash >= 4.
# DRY_RUN=1 prints every adb command instead of running it (no device or SDK needed).

ADB="${ADB:-adb}"
DRY_RUN="${DRY_RUN:-0}"
SERIAL="${SERIAL:-}"
DEVICE_DIR="${DEVICE_DIR:-/data/local/tmp/mosaic}"

die() { echo "error: $*" >&2; exit 2; }

# Print a command as a copy-pasteable shell line. An argument that is exactly $NAME (an unset variable the
# scripts leave to the shell that runs the line) is printed as "$NAME", so it expands there.
show() {
  local a out="" q="'"
  for a in "$@"; do
    if [[ "$a" =~ ^[A-Za-z0-9_./:=,@%+-]+$ ]]; then out+="$a "
    elif [[ "$a" =~ ^\$[A-Z_][A-Z0-9_]*$ ]]; then out+="\"$a\" "
    else out+="'${a//$q/$q\\$q$q}' "; fi
  done
  echo "${out% }"
}

# adb with the optional serial; in dry-run mode only printed.
adb_run() {
  local cmd=("$ADB")
  [[ -n "$SERIAL" ]] && cmd+=(-s "$SERIAL")
  cmd+=("$@")
  if [[ "$DRY_RUN" == 1 ]]; then show "${cmd[@]}"; else "${cmd[@]}"; fi
}

# The one BUNDLE positional argument: set_bundle ARG (call from the option loop), then check_bundle.
set_bundle() { [[ -z "$BUNDLE" ]] || die "one BUNDLE only (got '$BUNDLE' and '$1')"; BUNDLE="$1"; }
check_bundle() {
  [[ -n "$BUNDLE" ]] || { usage; die "BUNDLE folder missing"; }
  [[ -f "$BUNDLE/manifest.json" ]] || die "$BUNDLE/manifest.json not found (not a bundle folder)"
}

need_adb() {
  [[ "$DRY_RUN" == 1 ]] && return 0
  command -v "$ADB" >/dev/null 2>&1 || die "adb not found (install Android platform-tools or set ADB=...); use --dry-run to only print the commands"
}

# List the Android artifacts of a bundle, one per line:
#   role<TAB>variant<TAB>component<TAB>ort file<TAB>runtime-opt ort file (or -)<TAB>precision
list_android_models() {
  local bundle="$1"
  "${PYTHON:-python3}" - "$bundle" <<'PY'
import json, sys
from pathlib import Path
root = Path(sys.argv[1])
m = json.loads((root / "manifest.json").read_text())
n = 0
for role, rm in m.get("roles", {}).items():
    for v, vm in rm.get("variants", {}).items():
        if vm.get("target") != "android":
            continue
        comps = (vm.get("android") or {}).get("components", {})
        for c, cm in vm["components"].items():
            ro = (comps.get(c) or {}).get("runtime_opt", {}).get("file", "-")
            print("\t".join([role, v, c, cm["file"], ro, vm.get("precision", "?")]))
            n += 1
if n == 0:
    sys.exit(f"{root}/manifest.json lists no android variants: run `mosaic export --target android --out {root}` first")
PY
}
