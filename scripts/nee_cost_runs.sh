#!/bin/sh
# Throwaway measurement (issue 34, bench/frozen/nee_cost.md): bench/render_estimators.py before (a copy
# of main's tree at $BASE, built there) and after (this tree), interleaved, each printed to $OUT/<tag>.txt.
#   BASE=/tmp/nee34_base OUT=/tmp/nee34_runs sh scripts/nee_cost_runs.sh
set -eu
HERE=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$OUT"
run() {  # tag tree photons [extra args]
    tag=$1 tree=$2 n=$3
    shift 3
    (cd "$tree" && /usr/bin/python3 bench/render_estimators.py --photons "$n" --threads 2 "$@") > "$OUT/$tag.txt" 2>&1
    echo "$tag done $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$OUT/log.txt"
}
run after_200k_a "$HERE" 200000
run before_200k_a "$BASE" 200000
run after_200k_tau1_a "$HERE" 200000 --tau-cut 1
run after_200k_b "$HERE" 200000
run before_200k_b "$BASE" 200000
run after_200k_tau1_b "$HERE" 200000 --tau-cut 1
run after_1m "$HERE" 1000000
run before_1m "$BASE" 1000000
run after_1m_tau1 "$HERE" 1000000 --tau-cut 1
