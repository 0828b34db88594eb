#!/bin/bash
# Process CPU (user + sys, every thread) and wall of `mosaic eval scene` on the 7-Scenes kitchen, the code at
# commit BEFORE against this tree, runs interleaved (before, after, before, ...) so both see the same load.
# On the shared 2-core machine wall time carries other jobs' load; CPU seconds much less.
#
#   benchmarks/real_scene_cpu.sh BEFORE_COMMIT [BUNDLE] > benchmarks/results/real_scene_cpu.tsv
#
# BEFORE_COMMIT is unpacked with `git archive` into a temp dir and put first on PYTHONPATH for its runs.
set -euo pipefail
cd "$(dirname "$0")/.."
BEFORE=${1:?usage: $0 BEFORE_COMMIT [BUNDLE]}
BUNDLE=${2:-/work/bundles/real}
SHARED=${MOSAIC_SHARED:-../shared}
D=$SHARED/data/7scenes-redkitchen
A=benchmarks/data/redkitchen_annotation.json
PY=${PYTHON:-.venv/bin/python}
TMP=$(mktemp -d)
trap 'rm -rf "$TMP"' EXIT
mkdir -p "$TMP/pkg/mosaicthinker"
git archive "$BEFORE" | tar -x -C "$TMP/pkg/mosaicthinker"
echo -e "config\tk\tcode\twall_s\tuser_s\tsys_s\tmaxrss_kb\tload_before\tload_after"
AFTER=$(git rev-parse --short HEAD)
for cfg in "sensor sift 16" "sensor model 16" "model model 16" "sensor sift 32" "model model 32"; do
  read -r depth matcher k <<< "$cfg"
  for code in before after; do
    pp=""
    tag="after@$AFTER"
    if [ "$code" = before ]; then pp="$TMP/pkg"; tag="before@$BEFORE"; fi
    l0=$(cut -d' ' -f1 /proc/loadavg)
    PYTHONPATH=$pp /usr/bin/time -f "%e %U %S %M" -o "$TMP/time.txt" "$PY" -m mosaicthinker.runtime.cli eval scene \
      --data "$D" --annotations "$A" --bundle "$BUNDLE" --depth "$depth" --matcher "$matcher" --keyframes "$k" --json \
      --out "$TMP/out-$code" > /dev/null 2>&1
    read -r w u s m < "$TMP/time.txt"
    echo -e "$depth-$matcher\t$k\t$tag\t$w\t$u\t$s\t$m\t$l0\t$(cut -d' ' -f1 /proc/loadavg)"
  done
done
