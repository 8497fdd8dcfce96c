#!/bin/sh
# Throwaway measurement (issue 34, bench/frozen/nee_cost.md): bench/render_estimators.py at 2 threads,
# before (a copy of main's tree at $BASE, built there) and after (this tree), in the order given, each
# printed to $OUT/<tree>_<packets>_tau<tau_cut>_<i>.txt, with the load in $OUT/log.txt.
#   BASE=/tmp/nee34_base OUT=/tmp/nee34_runs sh scripts/nee_cost_runs.sh after:200000:3 before:200000:3 ...
set -eu
HERE=$(cd "$(dirname "$0")/.." && pwd)
mkdir -p "$OUT"
i=0
for spec in "$@"; do
    i=$((i + 1))
    tree=${spec%%:*} rest=${spec#*:}
    n=${rest%%:*} tau=${rest#*:}
    if [ "$tree" = before ]; then dir=$BASE extra=""; else dir=$HERE extra="--tau-cut $tau"; fi
    tag="${tree}_${n}_tau${tau}_$i"
    # shellcheck disable=SC2086
    (cd "$dir" && /usr/bin/python3 bench/render_estimators.py --photons "$n" --threads 2 $extra) > "$OUT/$tag.txt" 2>&1
    echo "$tag done $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> "$OUT/log.txt"
done
