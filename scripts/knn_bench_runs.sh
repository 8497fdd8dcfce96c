#!/bin/sh
# Throwaway (issue 34): the side-by-side bench, repeated and interleaved (200k and 10^6 packets), then the
# k choice at 10^6. Output in /tmp/knn_bench/.
cd "$(dirname "$0")/.." || exit 1
mkdir -p /tmp/knn_bench
for rep in 1 2 3; do
  for n in 200000 1000000; do
    echo "rep $rep n $n start $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> /tmp/knn_bench/log
    PYTHONPATH=python /usr/bin/python3 bench/render_estimators.py --photons $n --threads 2 --estimators kernel,knn,nee \
      > /tmp/knn_bench/bench_${n}_$rep.txt 2>&1
    echo "rep $rep n $n end $(date -u +%H:%M:%S) load $(cut -d' ' -f1-3 /proc/loadavg)" >> /tmp/knn_bench/log
  done
done
PYTHONPATH=python /usr/bin/python3 scripts/knn_choose_k.py --photons 1000000 --ks 16,32,64,128 --nee 0 > /tmp/knn_bench/choose_k_1e6.txt 2>&1
echo "all done $(date -u +%H:%M:%S)" >> /tmp/knn_bench/log
