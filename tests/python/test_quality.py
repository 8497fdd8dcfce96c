"""Quality presets are target accuracies with a packet cap (endophoton.quality)."""
import pytest

import endophoton as ep
from physics_helpers import assert_energy_conserved, K_SIGMA

VDH_RD = 0.09739  # van de Hulst, oracles §1


def _slab():
    s = ep.Scene(unit="cm")
    s.add_box("slab", (-100, -100, -0.02), (100, 100, 0), ep.Medium(mua=10, mus=90, g=0.75, n=1.0))
    return s


@pytest.mark.parametrize("name,rel", [("preview", 0.05), ("standard", 0.01)])
def test_preset_reaches_its_error_and_agrees_with_van_de_hulst(name, rel):
    res = ep.run(_slab(), ep.PencilSource((0, 0, 1), (0, 0, -1)), quality=name, seed=2, record_escapes=False)
    assert_energy_conserved(res)
    assert res.stop_reason == "target" and res.target_reached
    reached = res.diffuse_reflectance_stderr / res.diffuse_reflectance
    assert reached <= rel
    assert res.photons <= ep.QUALITY_PRESETS[name].max_photons
    assert abs(res.diffuse_reflectance - VDH_RD) < K_SIGMA * res.diffuse_reflectance_stderr + 5e-6


def test_presets_get_stricter_and_cost_more():
    a = ep.run(_slab(), ep.PencilSource((0, 0, 1), (0, 0, -1)), quality="preview", seed=1, record_escapes=False)
    b = ep.run(_slab(), ep.PencilSource((0, 0, 1), (0, 0, -1)), quality="standard", seed=1, record_escapes=False)
    # 1/sqrt(N): a 5x smaller error needs about 25x the packets. Preview cannot stop before
    # its 20 batches (5120 packets), where it is already below 5 %, so the ratio is smaller.
    assert a.diffuse_reflectance_stderr > 3 * b.diffuse_reflectance_stderr
    assert 4 * a.photons < b.photons < 60 * a.photons


def test_quality_excludes_other_budgets():
    with pytest.raises(ValueError, match="quality"):
        ep.run(_slab(), ep.PencilSource(), photons=100, quality="preview")
    with pytest.raises(ValueError, match=r"quality = 'reference' brings its own packet cap .*max_photons = 5000"):
        ep.run(_slab(), ep.PencilSource(), quality="reference", max_photons=5000)
    with pytest.raises(ValueError, match="quality = 'best'"):
        ep.run(_slab(), ep.PencilSource(), quality="best")
