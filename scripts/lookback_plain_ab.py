#!/usr/bin/env python3
"""Throwaway measurement (docs/performance.md §17): CPU s of a run without camera or records (colon scene,
spectral, 2 threads) with the package on PYTHONPATH; one JSON line. Run it alternately with two builds:

    PYTHONPATH=A/python /usr/bin/python3 scripts/lookback_plain_ab.py 300000
"""
import json
import os
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "bench"))
import endophoton as ep  # noqa: E402
from colon_scene import colon_scene  # noqa: E402

scene, rig = colon_scene(beta_deg=20.0)
photons = int(sys.argv[1]) if len(sys.argv) > 1 else 300_000
ep.run(scene, rig, 20_000, seed=9, threads=2, spectral=True, record_escapes=False)  # caches built
c0 = time.process_time()
r = ep.run(scene, rig, photons, seed=1, threads=2, spectral=True, record_escapes=False)
print(json.dumps(dict(path=ep.__file__, cpu_s=time.process_time() - c0, absorbed=r.absorbed)))
