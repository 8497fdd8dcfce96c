"""The main job's answer on the colon: append the comparison of the lights to OUT/report.md.

    /usr/bin/python3 scripts/main_job_answer.py OUT LABEL=SWEEP_DIR [LABEL=SWEEP_DIR ...] [--append FILE]

Reads each SWEEP_DIR/sweep.json (written by `python3 -m endophoton sweep`) and appends
endophoton.sweep.view_sweep.lights_report (each light's answer, its errors, the paper's 34°) to
OUT/report.md, with links to each sweep's own report; --append FILE appends FILE's text after it (the
Blender scene's section, which scripts/main_job_scene.py wrote while the sweeps ran).
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))

from endophoton.io import atomic_write_text  # noqa: E402
from endophoton.sweep.schema import SweepResult  # noqa: E402
from endophoton.sweep.view_sweep import lights_report  # noqa: E402


def main(argv) -> int:
    if len(argv) < 2:
        print(__doc__, file=sys.stderr)
        return 2
    extra = ""
    if "--append" in argv:
        i = argv.index("--append")
        if i + 1 >= len(argv):
            print("main_job_answer.py: --append needs a FILE", file=sys.stderr)
            return 2
        with open(argv[i + 1], encoding="utf-8") as fh:
            extra = fh.read()
        argv = argv[:i] + argv[i + 2 :]
    out, sweeps, links = argv[0], [], []
    for spec in argv[1:]:
        label, _, folder = spec.partition("=")
        sweeps.append((label, SweepResult.from_json(os.path.join(folder, "sweep.json"))))
        links.append(f"[{label}]({os.path.relpath(os.path.join(folder, 'report.md'), out)})")
    text = lights_report(sweeps) + "\nEach light's sweep report: " + ", ".join(links) + ".\n"
    path = os.path.join(out, "report.md")
    with open(path, encoding="utf-8") as fh:
        atomic_write_text(path, fh.read().rstrip("\n") + "\n\n" + text + extra)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
