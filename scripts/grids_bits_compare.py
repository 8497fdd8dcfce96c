"""Throwaway (issue 39): the colon with 0.2 mm grids, one worktree's build, printed as hashes of its
grids so that two builds (or thread counts) compare. argv: worktree threads [photons]."""
import hashlib, json, os, sys, tempfile

sys.path.insert(0, sys.argv[1] + "/python")
sys.path.insert(0, sys.argv[1] + "/bench")
import endophoton as ep
from endophoton import vdb
from colon_scene import colon_scene

scene, rig = colon_scene()
path = os.path.join(tempfile.mkdtemp(), "g.vdb")
n = int(sys.argv[3]) if len(sys.argv) > 3 else 20000
r = ep.run(scene, rig, photons=n, threads=int(sys.argv[2]), seed=1, grids=ep.GridRequest(voxel_size=2e-4, path=path))
out = {"absorbed_sum": r.grid_absorbed_sum.hex()}
for name in r.grid_names:
    items = sorted(
        (it["min"], it["max"], it["value"]) for it in vdb._read_grid(vdb._openvdb(), path, name).citerOnValues()
    )
    out[name] = [len(items), hashlib.sha256(repr(items).encode()).hexdigest()[:16]]
print(json.dumps(out))
