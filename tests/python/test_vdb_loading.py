"""The .vdb writer is a library of its own (native/vdb_library.h), loaded the first time a run writes
grids: a process that writes none never loads OpenVDB. Each case runs in a fresh interpreter, since a
library once loaded stays for the life of the process."""
import os
import shutil
import subprocess
import sys
import textwrap

import endophoton as ep

PACKAGE = os.path.dirname(os.path.abspath(ep.__file__))

# A clear absorbing box and a pencil beam (no fluorophores, so no data files are needed), and whether
# OpenVDB is mapped into the process.
PRELUDE = textwrap.dedent(
    """
    import os, sys
    import endophoton as ep

    def openvdb_loaded():
        with open("/proc/self/maps") as fh:
            return any("libopenvdb" in line for line in fh)

    def run(path=None, voxel_size=0.05):
        s = ep.Scene(unit="cm")
        s.add_box("absorber", (-1, -1, -1), (1, 1, 0), ep.Medium(mua=1.5, mus=10.0, g=0.0, n=1.0))
        grids = ep.GridRequest(voxel_size=voxel_size, path=path) if path else None
        return ep.run(s, ep.PencilSource((0, 0, 1.0), (0, 0, -1)), photons=200, seed=1, grids=grids)

    def refused(**kwargs):
        try:
            run(**kwargs)
        except ValueError as e:
            return str(e)
        raise SystemExit(f"no error for {kwargs}")
    """
)


def _python(code, package_parent, tmp_path):
    env = dict(os.environ, PYTHONPATH=package_parent)
    return subprocess.run(
        [sys.executable, "-c", PRELUDE + textwrap.dedent(code)],
        env=env,
        cwd=str(tmp_path),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_openvdb_is_loaded_only_to_write_grids(tmp_path):
    code = f"""
    assert not openvdb_loaded(), "import endophoton loaded OpenVDB"
    res = run()
    assert res.absorbed > 0
    assert not openvdb_loaded(), "a run without grids loaded OpenVDB"
    path = os.path.join({str(tmp_path)!r}, "g.vdb")
    # A grid run's checks before it traces need no OpenVDB: a bad path, and a voxel below the
    # smallest OpenVDB scales to (OpenVDB's rule, computed without it; test_vdb_writer.cpp).
    assert "grids.path" in refused(path=os.path.join({str(tmp_path)!r}, "no_such_dir", "g.vdb"))
    assert "grids.voxel_size" in refused(path=path, voxel_size=1e-6)
    assert not openvdb_loaded(), "a grid run's checks loaded OpenVDB"
    res = run(path)
    assert openvdb_loaded()
    assert "absorbed" in res.grid_names and os.path.getsize(path) > 0
    # The grid holds what the run absorbed (the writer's sum of the voxels).
    assert abs(res.grid_absorbed_sum - res.absorbed) <= 1e-9 * res.absorbed, (res.grid_absorbed_sum, res.absorbed)
    print("ok")
    """
    out = _python(code, os.path.dirname(PACKAGE), tmp_path)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_a_missing_writer_library_is_a_named_error_before_the_run(tmp_path):
    """A package without its writer library still runs without grids; a run with grids stops
    before tracing with an error that names the library and the way out, not a crash."""
    copy = tmp_path / "pkg" / "endophoton"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("libendophoton_vdb.so*", "__pycache__"))
    code = f"""
    assert os.path.dirname(ep.__file__) == {str(copy)!r}
    assert run().absorbed > 0
    try:
        run(os.path.join({str(tmp_path)!r}, "g.vdb"))
    except RuntimeError as e:
        print(str(e))
    else:
        raise SystemExit("no error")
    """
    out = _python(code, str(tmp_path / "pkg"), tmp_path)
    assert out.returncode == 0, out.stderr
    message = out.stdout.strip()
    assert "libendophoton_vdb.so.1" in message and "reinstall endophoton" in message, message
    assert not (tmp_path / "g.vdb").exists()
