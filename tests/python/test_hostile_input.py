"""Hostile input to the API: each is refused before any tracing with a ValueError that names the field and
its value, and leaves nothing changed on disk."""

import os
import stat

import numpy as np
import pytest

import endophoton as ep

M = ep.Medium(mua=0.1, mus=10.0, g=0.9, n=1.4)
DOWN = ep.PencilSource(position=(0, 0, 1), direction=(0, 0, -1))


def box_scene():
    s = ep.Scene(unit="cm")
    s.add_box("box", (-1, -1, -1), (1, 1, 0), M)
    return s


# ---- grids.path: checked before the run, never replaces a special file or a link


def run_with_grid(path):
    return ep.run(box_scene(), DOWN, photons=100, grids=ep.GridRequest(0.1, str(path)))


def test_grid_path_fifo_is_refused_and_kept(tmp_path):
    fifo = tmp_path / "fifo1"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=f"grids.path = '{fifo}' exists and is a FIFO"):
        run_with_grid(fifo)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["fifo1"]


def test_grid_path_symlink_is_refused_and_its_target_kept(tmp_path):
    target = tmp_path / "target.vdb"
    target.write_text("kept")
    link = tmp_path / "link.vdb"
    link.symlink_to(target)
    with pytest.raises(ValueError, match=f"grids.path = '{link}' exists and is a symbolic link"):
        run_with_grid(link)
    assert link.is_symlink() and target.read_text() == "kept"


def test_grid_path_directory_is_refused(tmp_path):
    with pytest.raises(ValueError, match=f"grids.path = '{tmp_path}' exists and is a directory"):
        run_with_grid(tmp_path)


def test_grid_path_in_missing_directory_is_refused_before_tracing(tmp_path):
    path = tmp_path / "nodir" / "g.vdb"
    with pytest.raises(ValueError, match=f"grids.path = '{path}' is in the directory '{path.parent}'"):
        # 10^12 packets would take hours: the refusal must come first.
        ep.run(box_scene(), DOWN, photons=10**12, grids=ep.GridRequest(0.1, str(path)))


def test_grid_path_with_too_long_name_is_refused(tmp_path):
    path = tmp_path / ("x" * 300)
    with pytest.raises(ValueError, match="grids.path = .* has a file name of 300 characters"):
        run_with_grid(path)
    assert os.listdir(tmp_path) == []


def test_grid_path_regular_file_is_replaced_atomically(tmp_path):
    path = tmp_path / "g.vdb"
    path.write_text("old")
    r = run_with_grid(path)
    assert r.to_dict()["grid_path"] == str(path)
    assert path.read_bytes()[:4] == b" BDV"  # the OpenVDB magic number 0x56444220: the new file
    assert os.listdir(tmp_path) == ["g.vdb"]
