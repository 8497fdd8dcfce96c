"""Cancel latency through the add-on (issue 36): opens a .blend (default blend_scenes/colon_polyp.blend),
starts the Run Simulation job as the modal operator does (simulation.prepare_job, interactive), cancels it
after ``--after`` seconds as Esc does (job.cancel()) and prints the time from cancel() to the worker's end
(what the add-on's drain timer waits), for its settings and at 1 and 2 threads. A measurement, not a test.

    ENDOPHOTON_PYTHONPATH=$PWD/python nice blender -b --factory-startup --python scripts/cancel_latency_blender.py \
        -- [--blend FILE] [--after 2] [--repeat 3]
"""

import argparse
import os
import sys
import time

import bpy

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(REPO, "tests", "blender"))
if os.environ.get("ENDOPHOTON_PYTHONPATH"):  # before any installed endophoton
    sys.path.insert(0, os.environ["ENDOPHOTON_PYTHONPATH"])
from conftest import ensure_addon  # noqa: E402


class _TimedEngine:
    """The engine module, with the return time of its run() noted (the engine's part of the wait)."""

    def __init__(self, ep):
        self._ep, self.returned_at = ep, None

    def __getattr__(self, name):
        return getattr(self._ep, name)

    def run(self, *a, **kw):
        try:
            return self._ep.run(*a, **kw)
        finally:
            self.returned_at = time.monotonic()


def measure(threads, after_s):
    from endophoton_addon import simulation

    bpy.context.scene.endophoton.threads = threads
    job = simulation.prepare_job(bpy.context, interactive=True)
    job.ep = engine = _TimedEngine(job.ep)
    job.start()
    time.sleep(after_s)
    done_at_cancel = job.progress().done
    job.cancel()
    job.wait()
    simulation.discard_job(job)
    r = job.result
    packets = None if r is None else f"{r.photons:,} ({r.stop_reason})"
    in_run = (engine.returned_at or job.finished_at) - job.cancelled_at
    return job.finished_at - job.cancelled_at, in_run, done_at_cancel, packets, job.error


def main():
    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    ap = argparse.ArgumentParser()
    ap.add_argument("--blend", default=os.path.join(REPO, "blend_scenes", "colon_polyp.blend"))
    ap.add_argument("--after", type=float, default=2.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quality", default="", help="PREVIEW, STANDARD, REFERENCE (default: the file's)")
    a = ap.parse_args(argv)
    bpy.ops.wm.open_mainfile(filepath=a.blend)
    ensure_addon()
    s = bpy.context.scene.endophoton
    if a.quality:
        s.quality = a.quality
    print(f"{os.path.basename(a.blend)}: quality {s.quality}, grids {s.output_grids}, cancel after {a.after:g} s")
    for threads in (1, 2):
        for _ in range(a.repeat):
            latency, in_run, done, packets, error = measure(threads, a.after)
            print(
                f"threads {threads}: cancel -> worker end {1e3 * latency:8.1f} ms (-> ep.run returned "
                f"{1e3 * in_run:.1f} ms); progress at cancel {done:,}, "
                f"merged packets {packets}, error {error!r}",
                flush=True,
            )


main()
