"""Edges far from the origin (docs/numerics.md, "Edges far from the origin"): crossings closer than the
grouping tolerance 2e-6 (|p| + t) + 1e-7 extent are one crossing, so light that reaches a region's edge is
resolved only to that tolerance, which grows with the distance from the origin. The run warns, naming the
region, when the tolerance exceeds 5 % of the region's mean free path; below that an edge-dominated case
agrees with the same scene at the origin."""
import math

import pytest

import endophoton as ep
from physics_helpers import assert_energy_conserved

MEDIUM = ep.Medium(mua=10.0, mus=90.0, g=0.0, n=1.5)  # mean free path 0.01 cm


def edge_run(offset_cm, photons, seed=1):
    """A pencil beam one mean free path from the edge of a 40 cm box whose top-face centre is at
    (offset, 0, offset) cm: most of its light reaches the box's edge."""
    scene = ep.Scene("cm")
    scene.add_box("tissue", (offset_cm - 20, -20, offset_cm - 40), (offset_cm + 20, 20, offset_cm), MEDIUM)
    source = ep.PencilSource((offset_cm + 19.99, 0, offset_cm + 1), (0, 0, -1))
    return ep.run(scene, source, photons=photons, seed=seed, threads=2, record_escapes=False)


@pytest.mark.parametrize("offset_cm, ratio", [(300.0, 0.0644), (1e4, 2.0)])
def test_far_edges_are_named_in_a_warning(offset_cm, ratio):
    """Tolerance 2e-6 (|p| + mfp) + 1e-7 extent at |p| = offset + 20 cm: 0.0644 and 2.0 mean free paths."""
    res = edge_run(offset_cm, 1000)
    assert_energy_conserved(res)
    assert len(res.warnings) == 1
    w = res.warnings[0]
    assert w.startswith("region 'tissue': at |coordinate| up to ")
    assert f"{ratio:.3g} of its mean free path (0.01 scene units)" in w
    assert "Edges far from the origin" in w


def test_near_edges_give_no_warning():
    assert edge_run(0.0, 1000).warnings == []
    assert edge_run(150.0, 1000).warnings == []  # tolerance 0.034 mean free paths


def test_below_the_warning_an_edge_case_agrees_with_the_origin():
    """150 cm away (no warning) the edge-dominated absorbed and transmitted fractions equal the origin's
    within 3 sigma of the two independent runs (at 1e4 cm, with the warning, absorbed was 0.622 against
    0.600, 40 sigma)."""
    near, far = edge_run(0.0, 100_000, seed=3), edge_run(150.0, 100_000, seed=4)
    for key in ("absorbed", "transmittance", "diffuse_reflectance"):
        a, b = getattr(near, key), getattr(far, key)
        sigma = math.hypot(getattr(near, key + "_stderr"), getattr(far, key + "_stderr"))
        assert abs(a - b) < 3 * sigma, (key, a, b, sigma)
