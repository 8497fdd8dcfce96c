"""Colon scene (bench/colon_scene.py) with grids: packets/s (engine seconds and CPU seconds) and peak RSS
(VmHWM) in a fresh process. argv: worktree threads voxel_m [photons [cache_store_mb]] [only=q1,q2] (voxel_m 0:
no grids; cache_store_mb: the per-cube triangle caches' budget, Scene(cache_store_mb=), default the engine's;
only=: the grid quantities asked for, of absorbed, fluorescent_light, emission; default all three)."""
import json, os, resource, sys, time, tempfile

sys.path.insert(0, sys.argv[1] + "/python")
sys.path.insert(0, sys.argv[1] + "/bench")
import endophoton as ep
from colon_scene import colon_scene

only = [a for a in sys.argv if a.startswith("only=")]
sys.argv = [a for a in sys.argv if not a.startswith("only=")]
quantities = {"absorbed", "fluorescent_light", "emission"}
asked = set(only[0][5:].split(",")) if only else quantities
threads = int(sys.argv[2])
voxel = float(sys.argv[3])
n = int(sys.argv[4]) if len(sys.argv) > 4 else 150000
scene, rig = colon_scene()
if len(sys.argv) > 5:
    scene.cache_store_mb = float(sys.argv[5])


def hwm():
    for l in open("/proc/self/status"):
        if l.startswith("VmHWM"):
            return int(l.split()[1]) / 1024


ep.run(scene, rig, photons=2000, threads=threads)
base = hwm()
path = os.path.join(tempfile.mkdtemp(), "g.vdb")
switches = {q: q in asked for q in quantities} if only else {}  # none: the default (every worktree)
grids = ep.GridRequest(voxel_size=voxel, path=path, **switches) if voxel > 0 else None
ru0 = resource.getrusage(resource.RUSAGE_SELF)
r = ep.run(scene, rig, photons=n, threads=threads, seed=1, grids=grids)
ru1 = resource.getrusage(resource.RUSAGE_SELF)
cpu = ru1.ru_utime - ru0.ru_utime + ru1.ru_stime - ru0.ru_stime
print(
    json.dumps(
        dict(
            threads=threads,
            voxel=voxel,
            pps=round(r.photons / r.seconds),
            pp_cpu_s=round(r.photons / cpu),
            sys_s=round(ru1.ru_stime - ru0.ru_stime, 2),
            base_mb=round(base),
            peak_mb=round(hwm()),
            vdb_mb=round(os.path.getsize(path) / 1e6, 2) if grids else 0,
            cache_mb=round(scene.to_native().cache_store_bytes / 2**20),
            grids=r.grid_names,
        )
    )
)
