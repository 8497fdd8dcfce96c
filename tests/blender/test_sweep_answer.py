# SPDX-License-Identifier: MIT
"""Issue 36, defect 2: the Sweep β panel answers "at which β is the polyp most visible?" — target
and background pickers, a visibility sweep through the operator, the contrast-against-β plot loaded
as an image, the answer with its error and verdict in the summary and in report.md, every panel
line readable at the default sidebar width, the energy maximum labelled as energy."""

import os

import bpy
import pytest

from endophoton_addon import panels, sweep_answer, sweep_job
from conftest import data_snapshot, open_blend

BETAS = "0,10,20,30,40"


def _setup(tmp_path):
    scene = open_blend("flat_tissue.blend", tmp_path / "grids")
    s = scene.endophoton.sweep
    s.betas, s.store, s.seed, s.threads, s.keep_runs = BETAS, 1_500, 3, 1, "OFF"
    s.output_dir = str(tmp_path / "sweep")
    s.view_size = 32
    return scene, s


class _Lines:
    """Stands in for a panel column: collects the label texts drawn."""

    def __init__(self):
        self.lines = []

    def label(self, text="", **_kw):
        self.lines.append(text)

    def row(self, **_kw):
        return self

    def separator(self, **_kw):
        pass


def test_pickers_list_the_regions_polyp_first_for_the_target(tmp_path):
    scene, s = _setup(tmp_path)
    assert [i[0] for i in sweep_answer.region_items(scene, "target")] == ["Polyp", "Tissue"]
    assert [i[0] for i in sweep_answer.region_items(scene, "background")] == ["Tissue", "Polyp"]
    assert (s.target_region, s.background_region, s.visibility) == ("Polyp", "Tissue", True)


def test_target_equal_to_background_is_refused_by_field(ep, tmp_path):
    _scene, s = _setup(tmp_path)
    s.background_region = "Polyp"
    before = data_snapshot()
    with pytest.raises(RuntimeError, match=r"sweep.target_region = sweep.background_region = 'Polyp'"):
        bpy.ops.endophoton.sweep_beta()
    assert data_snapshot() == before and not os.path.exists(s.output_dir)


@pytest.mark.slow
def test_visibility_sweep_answers_with_error_and_verdict(ep, tmp_path):
    scene, s = _setup(tmp_path)
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    summary = scene[sweep_job.SUMMARY_KEY].to_dict()
    assert summary["visibility_target"] == "Polyp" and summary["visibility_background"] == "Tissue"
    assert summary["visibility_answer"] and summary["visibility_verdict"]
    # The answer is the report's: report.md carries the same sentence.
    with open(os.path.join(s.output_dir, "report.md"), encoding="utf-8") as f:
        report = f.read()
    assert "## At which β is the polyp most visible?" in report
    assert summary["visibility_answer"][:60] in report.replace("**", "")
    # The contrast-against-β plot is loaded with the sweep's images.
    plot = bpy.data.images[sweep_job.image_name("visibility.png")]
    assert plot.get(sweep_job.IMAGE_KEY) and plot.size[0] > 0
    rows = sweep_job.summary_rows(scene)
    labels = [label for label, _value in rows]
    assert labels[:1] == ["Question"] and "Verdict" in labels and "Answer" in labels
    assert "Energy max β (sum)" in labels and "Best β (sum)" not in labels
    col = _Lines()
    panels.draw_rows(col, rows)
    assert all(len(line) <= panels.SIDEBAR_CHARS for line in col.lines)
    assert " ".join(col.lines).count("…") == sum(value.count("…") for _label, value in rows)  # nothing cut


def test_rows_wrap_instead_of_being_cut():
    """At the default width a long row is wrapped, every word kept (the panel used to split
    label | value and cut both: 'Best β (s… 55.0 ± 5.3° at r…')."""
    rows = [("Energy max β (sum)", "55.0 ± 5.3° at range edge deg-6 fit"), ("Time", "3.2 s")]
    col = _Lines()
    panels.draw_rows(col, rows)
    assert all(len(line) <= panels.SIDEBAR_CHARS for line in col.lines)
    assert " ".join(col.lines).split() == "Energy max β (sum): 55.0 ± 5.3° at range edge deg-6 fit Time: 3.2 s".split()


def test_estimator_goes_into_the_visibility_request(tmp_path):
    """The Visibility box's Estimator is the sweep's --estimator: exitance by default (as the command line's),
    kernel and nee on request."""
    scene, s = _setup(tmp_path)
    names = ["Polyp", "Tissue"]
    assert s.view_estimator == "EXITANCE"
    assert sweep_answer.visibility_request(s, names, "test")["estimator"] == "exitance"
    s.view_estimator = "KERNEL"
    assert sweep_answer.visibility_request(s, names, "test")["estimator"] == "kernel"
    s.view_estimator = "NEE"
    req = sweep_answer.visibility_request(s, names, "test")
    assert req == {"target": "Polyp", "background": "Tissue", "width": 32, "height": 32, "estimator": "nee"}


@pytest.mark.slow
def test_next_event_sweep_answers_from_its_own_tallies(ep, tmp_path):
    """Estimator = Next Event: every β's view comes from runs with the camera tally (no white pass), the
    report says so, and the panel's answer is there."""
    scene, s = _setup(tmp_path)
    s.betas, s.view_size, s.view_estimator = "0,30", 16, "NEE"
    assert bpy.ops.endophoton.sweep_beta() == {"FINISHED"}
    summary = scene[sweep_job.SUMMARY_KEY].to_dict()
    assert summary["visibility_answer"]
    with open(os.path.join(s.output_dir, "report.md"), encoding="utf-8") as f:
        report = f.read()
    assert "`nee` estimator's own tallies" in report and "white pass" not in report
    with open(os.path.join(s.output_dir, "sweep.csv"), encoding="utf-8") as f:
        header, *lines = f.read().splitlines()
    cols = header.split(",")
    for line in lines:
        row = dict(zip(cols, line.split(",")))
        assert row["white_packets"] == row["view_packets"] == row["packets_traced"]
