"""Throwaway (issue 39): VmRSS of the colon run with 0.2 mm grids sampled every 50 ms from a thread, to see
whether the peak lies in the tracing or in the .vdb write. argv: worktree threads."""
import os, sys, tempfile, threading, time

sys.path.insert(0, sys.argv[1] + "/python")
sys.path.insert(0, sys.argv[1] + "/bench")
import endophoton as ep
from colon_scene import colon_scene


def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024


scene, rig = colon_scene()
ep.run(scene, rig, photons=2000, threads=1)
samples, done = [], threading.Event()


def sample():
    while not done.is_set():
        samples.append((time.monotonic(), rss_mb()))
        time.sleep(0.01)


path = os.path.join(tempfile.mkdtemp(), "g.vdb")
threading.Thread(target=sample, daemon=True).start()
t0 = time.monotonic()
import ctypes


class MallInfo2(ctypes.Structure):
    _fields_ = [
        (f, ctypes.c_size_t)
        for f in "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()
    ]


libc = ctypes.CDLL("libc.so.6")
libc.mallinfo2.restype = MallInfo2
last_progress = [0.0, 0, None]


def progress(done, total):
    mi = libc.mallinfo2()
    last_progress[:] = [
        time.monotonic(),
        done,
        {f: round(getattr(mi, f) / 2**20, 1) for f in ("arena", "hblkhd", "fordblks")},
    ]


r = ep.run(
    scene,
    rig,
    photons=150000,
    threads=int(sys.argv[2]),
    seed=1,
    grids=ep.GridRequest(voxel_size=2e-4, path=path),
    progress=progress,
)
done.set()
peak_t, peak = max(samples, key=lambda s: s[1])
print(f"run {time.monotonic() - t0:.1f} s; peak RSS {peak:.0f} MB at {peak_t - t0:.1f} s; file written at the end")
for t, m in samples[:: max(1, len(samples) // 25)] + [s for s in samples if s[0] > samples[-1][0] - 1.0][::5]:
    print(f"{t - t0:6.2f} s {m:6.0f} MB")
mi = libc.mallinfo2()
print({f: round(getattr(mi, f) / 2**20, 1) for f in ("arena", "hblkhd", "uordblks", "fordblks")}, "MB")
print(f"last {samples[-1][0] - t0:.2f} s {samples[-1][1]:.0f} MB")
print(
    f"last progress call at {last_progress[0] - t0:.2f} s, {last_progress[1]} packets done, malloc MB {last_progress[2]}"
)
