#!/bin/sh
# Issue 39: packets per CPU-second of seed tissue and the MCML slab with today's
# scalar engine, 1 and 2 threads, interleaved repeats (the CLI's run_cpu_seconds:
# the CPU time of the ep.run call, scene build included). Throwaway measurement.
#   PYTHONPATH=python sh scripts/lanes_seed_cpu.sh 5 > /tmp/lanes_cpu.txt
reps=${1:-5}
for r in $(seq "$reps"); do
  for scene in seed_tissue:200000 mcml_slab:1000000; do
    for t in 1 2; do
      name=${scene%%:*}; n=${scene##*:}
      /usr/bin/python3 -m endophoton run "examples/$name.json" --photons "$n" --threads "$t" --stats |
        /usr/bin/python3 -c "import json,sys,os; d=json.load(sys.stdin); c=d['stats']['process']['run_cpu_seconds']; print('$name', $t, $n, round(c,3), round($n/c), os.getloadavg()[0], d['diffuse_reflectance'])"
    done
  done
done
